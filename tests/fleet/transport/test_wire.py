"""The fleet's wire format and keys: what crosses Zenoh is validated, and names are single chunks.
"""

from __future__ import annotations

import json
import re

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import (
    TICK_LIMIT,
    CurrentTraj,
    Message,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    TaskId,
)
from fleet.transport.keys import FleetKeys, check_name
from fleet.transport.wire import (
    STAMP_AHEAD_STEPS,
    VERSION,
    Body,
    MailOrder,
    PeerBounds,
    WireError,
    answer_in,
    answers,
    checked,
    decode,
    encode,
    from_core,
    proposing,
    to_core,
    to_json,
)

TASK = TaskId(12, "d1", 3)


@pytest.mark.parametrize("message", [
    ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2", "d3")),
    CurrentTraj("d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), TASK),
    PlanProposal("d1", TASK, Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2",), direct=True),
    PlanAck("d1", TaskId(9, "d2", 1), Trajectory(40, ((1, 2, 0),)), direct=True),
    PlanRefusal("d1", TaskId(9, "d2", 1), direct=True),
])
def test_protocol_messages_round_trip(message: object) -> None:
    envelope = decode(encode("d1", 5.5, from_core(message)))  # type: ignore[arg-type]
    assert envelope.sender == "d1" and envelope.sent_at == 5.5
    assert to_core(envelope, "d2") == message


def test_one_answer_to_several_drones_is_each_ones_answer_and_nothing_to_the_others() -> None:
    trajectory = Trajectory(40, ((1, 2, 0), (2, 2, 0)))
    asked_by_d3, asked_by_d4 = TaskId(12, "d3", 1), TaskId(13, "d4", 2)
    envelope = decode(encode("d1", 5.5, answers(trajectory, {"d3": asked_by_d3, "d4": asked_by_d4})))
    assert to_core(envelope, "d3") == CurrentTraj("d1", trajectory, asked_by_d3)
    assert to_core(envelope, "d4") == CurrentTraj("d1", trajectory, asked_by_d4)
    assert to_core(envelope, "d5") is None


def envelope(body: dict[str, object], **over: object) -> bytes:
    return json.dumps({"v": VERSION, "sender": "d2", "sent_at": 1.0, "body": body, **over}).encode()


@pytest.mark.parametrize("payload, problem", [
    (b"not json", "JSON is malformed"),
    (b'{"v": 16, "sender": "d\xff", "sent_at": 1.0, "body": {"kind": "clock_ping"}}', "UTF-8"),
    (envelope({"kind": "clock_ping"}, v=3), "Invalid enum value 3 - at `$.v`"),
    (envelope({"kind": "teleport"}), "Invalid value 'teleport' - at `$.body.kind`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": "12", "drone": "d1", "seq": 1}}),
     "Expected `int`, got `str` - at `$.body.task_id.stamp`"),
    (envelope({"kind": "cur_traj", "in_reply_to": {"stamp": 1, "drone": "d1", "seq": 1, "tick": 2**32 + 1},
               "trajectory": {"start_step": 3, "cells": [[1, 1, 0]]}}),
     "at `$.body.in_reply_to.tick`"),  # a hybrid clock moves its stamp on before this
    (envelope({"kind": "cur_traj_to", "replies": {}, "trajectory": {"start_step": 3, "cells": [[1, 1, 0]]}}),
     "at `$.body.replies`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": 1, "drone": "d1", "seq": 1}, "extra": 1}),
     "unknown field `extra`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": 1, "drone": "d1", "seq": 1}}),
     "missing required field `trajectory` - at `$.body`"),  # a drone before it in line takes it as its answer
    (envelope({"kind": "cur_traj", "in_reply_to": {"stamp": 1, "drone": "d1", "seq": 1},
               "trajectory": {"start_step": 3, "cells": []}}),
     "at `$.body.trajectory.cells`"),
    (envelope({"kind": "mail", "id": "m/1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5}),
     "at `$.body.id`"),
    (envelope({"kind": "mail", "id": "m1\n", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5}),
     "at `$.body.id`"),  # a Zenoh key chunk: no newline, even a final one
    (envelope({"kind": "held", "drone": "d1", "mail": [{"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0],
                                                        "priority": 42, "stage": "queued"}]}),
     "at `$.body.mail[0].priority`"),  # what an heir takes over is checked as an order is
    (envelope({"kind": "mail", "id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 10}),
     "Expected `int` <= 9 - at `$.body.priority`"),
])
def test_a_malformed_or_foreign_payload_is_refused_naming_what_is_wrong(payload: bytes, problem: str) -> None:
    with pytest.raises(WireError, match="malformed message") as caught:
        decode(payload)
    assert problem in str(caught.value)


def test_a_payload_handed_to_every_drone_of_a_process_is_validated_once() -> None:
    payload = encode("d1", 2.0, from_core(CurrentTraj("d1", Trajectory(3, ((1, 1, 0), (1, 2, 0))), TASK)))
    first = decode(payload)
    assert decode(bytes(bytearray(payload))) is first  # equal (not the same) bytes: validated already
    broken = payload.replace(b'"cells"', b'"cels"')
    for _ in range(2):  # a bad payload is refused every time, not remembered as good
        with pytest.raises(WireError, match="cels"):
            decode(broken)


def test_a_task_ids_tick_travels() -> None:
    proposal = PlanProposal("d1", TaskId(40, "d1", 3, epoch=2, tick=17), Trajectory(40, ((1, 2, 0),)))
    assert to_core(decode(encode("d1", 5.5, from_core(proposal))), "d2") == proposal


def test_the_wire_format_is_the_documented_json() -> None:
    """Other tools read these bytes: the envelope's fields in order, the body tagged by its kind."""
    request = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2",))
    payload = encode("d1", 5.5, from_core(request))
    assert payload == (b'{"v":16,"sender":"d1","sent_at":5.5,"body":{"kind":"req_traj",'
                       b'"task_id":{"stamp":%d,"drone":"%s","seq":%d,"epoch":0,"tick":0},'
                       b'"trajectory":{"start_step":40,"cells":[[1,2,0],[2,2,0]]},"asked":["d2"],"holds":[],"clear":[]}}'
                       % (TASK.stamp, TASK.drone.encode(), TASK.seq))


def test_the_cells_a_lost_vehicle_holds_travel_with_requests_and_answers() -> None:
    """A drone whose vehicle is lost names the cells it may be in; a peer's stack must get them as sent."""
    held = ((1, 2, 0), (2, 2, 0), (3, 2, 0))
    request = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2",), held)
    assert to_core(decode(encode("d1", 5.5, from_core(request))), "d2") == request
    asking = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0),)), ("d2",), clear=((2, 2, 0), (3, 2, 0)))
    assert to_core(decode(encode("d1", 5.5, from_core(asking))), "d2") == asking
    answer = CurrentTraj("d1", Trajectory(40, ((1, 2, 0),)), TASK, held)
    assert to_core(decode(encode("d1", 5.5, from_core(answer))), "d2") == answer
    joined = answers(answer.trajectory, {"d2": TASK, "d3": TASK}, held)
    assert to_core(decode(encode("d1", 5.5, joined)), "d3") == answer


def test_an_answer_with_a_proposal_rides_in_the_proposal_to_everyone() -> None:
    """A plan proposed answers the drones that waited for it: each takes its answer (where the sender is
    now, and the proposal) out of the one ``propose`` everyone gets, and holds the proposal as any."""
    held = ((5, 5, 0),)
    proposal = PlanProposal("d1", TaskId(11, "d1", 2), Trajectory(42, ((1, 2, 0), (1, 3, 0))), ("d2", "d3"))
    by_d3, by_d4 = TaskId(12, "d3", 1), TaskId(13, "d4", 1)
    answer = CurrentTraj("d1", Trajectory(40, ((1, 2, 0),)), by_d3, held, proposal)
    alone = decode(encode("d1", 5.5, from_core(answer)))  # sent on its own, it is a proposal too
    assert to_core(alone, "d3") == proposal and answer_in(alone, "d3") == answer and answer_in(alone, "d2") is None
    joined = decode(encode("d1", 5.5, proposing(proposal, {"d3": by_d3, "d4": by_d4}, answer.trajectory, held)))
    assert to_core(joined, "d2") == proposal
    assert answer_in(joined, "d3") == answer
    assert answer_in(joined, "d4") == CurrentTraj("d1", answer.trajectory, by_d4, held, proposal)
    assert answer_in(joined, "d2") is None
    mute = decode(encode("d1", 5.5, proposing(proposal, {"d3": by_d3})))
    with pytest.raises(WireError, match="propose from 'd1' answers requests but says nothing of what it flies"):
        answer_in(mute, "d3")


@pytest.mark.parametrize("message", [
    ReqForCurrentTraj(TaskId(12, "d3", 1), "d1", Trajectory(40, ((1, 2, 0),)), ("d2",)),
    PlanProposal("d1", TaskId(12, "d3", 1), Trajectory(42, ((1, 2, 0),)), ("d2",)),
    PlanDecision("d1", TaskId(12, "d3", 1), Trajectory(42, ((1, 2, 0),)), flown=True),
])
def test_a_request_proposal_or_decision_for_another_drones_task_is_refused(message: Message) -> None:
    """A task id stands for its drone in the line: d1 may not coordinate d3's task."""
    envelope = decode(encode("d1", 5.5, from_core(message)))
    with pytest.raises(WireError, match=re.escape("from 'd1' names task 12.d3.1 of drone 'd3'")):
        to_core(envelope, "d2")


def test_an_answer_riding_in_a_proposal_for_another_drones_task_is_refused() -> None:
    proposal = PlanProposal("d1", TaskId(12, "d3", 1), Trajectory(42, ((1, 2, 0),)), ("d2",))
    envelope = decode(encode("d1", 5.5, proposing(proposal, {"d2": TASK}, Trajectory(40, ((1, 2, 0),)))))
    with pytest.raises(WireError, match=re.escape("propose from 'd1' names task 12.d3.1 of drone 'd3'")):
        answer_in(envelope, "d2")


def test_what_a_proposal_says_its_sender_flies_is_bounded_as_any_trajectory() -> None:
    proposal = PlanProposal("d1", TaskId(11, "d1", 2), Trajectory(42, ((1, 2, 0),)), ("d2",))
    body = proposing(proposal, {"d2": TASK}, Trajectory(40, ((9, 2, 0),)))
    with pytest.raises(WireError, match=r"cell \[9, 2, 0\] is outside the 8x8x1 workspace"):
        PeerBounds.of((8, 8, 1), 20).check(body, 40)
    PeerBounds.of((8, 8, 1), 20).check(proposing(proposal, {"d2": TASK}, Trajectory(40, ((7, 2, 0),))), 40)


def test_a_tick_at_its_limit_counts_as_the_next_stamp_against_the_bound_ahead() -> None:
    """A clock that sees an id whose tick is at its limit moves its stamp on a step: at the bound, that
    id would make honest drones send ids their peers refuse. So the id itself is refused."""
    bounds, now = PeerBounds.of((8, 8, 1), 20), 100

    def proposal(tick: int) -> Body:
        task = TaskId(now + STAMP_AHEAD_STEPS, "d1", 1, tick=tick)
        return decode(encode("d1", 5.5, from_core(PlanProposal("d1", task, Trajectory(42, ((7, 2, 0),)))))).body

    bounds.check(proposal(TICK_LIMIT - 1), now)
    with pytest.raises(WireError, match="1001 steps ahead"):
        bounds.check(proposal(TICK_LIMIT), now)


def test_a_body_within_bounds_is_checked_once_for_every_drone_but_not_for_other_bounds_or_steps() -> None:
    """The drones of a process share a decoded envelope; what one found within bounds holds for the others,
    at that step or later, in that workspace only."""
    stamp = 3000
    body = decode(encode("d1", 5.5, from_core(PlanProposal("d1", TaskId(stamp, "d1", 1),
                                                           Trajectory(42, ((7, 2, 0),)), ("d2",))))).body
    wide, narrow = PeerBounds.of((8, 8, 1), 20), PeerBounds.of((4, 4, 1), 20)
    wide.check(body, stamp)
    wide.check(body, stamp + 5)
    with pytest.raises(WireError, match=r"cell \[7, 2, 0\] is outside the 4x4x1 workspace"):
        narrow.check(body, stamp)
    with pytest.raises(WireError, match="steps ahead of this clock"):
        wide.check(body, stamp - 1001)
    wide.check(body, stamp)


def test_a_message_built_by_hand_is_checked_as_one_from_the_wire() -> None:
    order = checked(MailOrder, id="m1", pickup=[1, 2, 0], dropoff=[3, 4, 0], priority=5)
    assert decode(encode("cli", 0.0, order)).body == order
    assert to_json(order) == {"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5, "note": None}
    for fields, problem in (({"pickup": [1, 2]}, "at `$.pickup`"), ({"priority": 12}, "at `$.priority`"),
                            ({"id": "m 1"}, "at `$.id`")):
        with pytest.raises(WireError, match=re.escape(problem)):
            checked(MailOrder, **{"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5, **fields})


def test_a_non_protocol_body_is_not_taken_for_a_protocol_message() -> None:
    order = MailOrder(id="m1", pickup=[1, 2, 0], dropoff=[3, 4, 0], priority=5)
    with pytest.raises(WireError, match="not a protocol message"):
        to_core(decode(encode("cli", 0.0, order)), "d1")


def test_keys_live_under_the_fleet_and_names_must_be_single_chunks() -> None:
    keys = FleetKeys("north")
    assert keys.proto("d1", "d2") == "drona/north/proto/d2/d1"
    assert keys.alive() == "drona/north/alive/*"
    assert keys.last_chunk(keys.status(mail="m-1")) == "m-1"
    # Whoever writes a key is named in it: the access control lets only that drone write there.
    written = [keys.proto("d1", "d2"), keys.proto("all", "d2"), keys.answers("d2"), keys.plan("d2"),
               keys.state("d2"), keys.held("d2"), keys.status("d2", "m-1"), keys.alive("d2")]
    assert {keys.writer(key) for key in written} == {"d2"}
    for bad in ("a/b", "*", "", "d 1", "d1\n"):
        with pytest.raises(ValueError, match="Zenoh key chunk"):
            check_name("drone", bad)
