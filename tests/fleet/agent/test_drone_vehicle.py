"""One drone's agent and its vehicle: down, waiting for its position, lost and back, late, and the
flight record of its sightings.
"""

from __future__ import annotations

import asyncio
import io
import json

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.stack.messages import CurrentTraj, Message, PlanAck, ReqForCurrentTraj, TaskId
from drona_gcs.stack.protocol import State
from drona_gcs.workspace import Workspace
from fleet.agent.drone import DroneAgent
from fleet.setpoint_loop import Sample, StepReport
from fleet.transport.wire import (
    MailOrder,
    MailStatus,
    PlanAnnounce,
    Propose,
    ReqTraj,
    decode,
    encode,
    from_core,
    to_core,
)
from tests.fakes.node import FakeNode
from tests.fakes.vehicle import FakeVehicle
from tests.fleet.agent.drone_helpers import FRAME, KEYS, WS, statuses, vehicle_over_its_start
from tests.fleet.vehicle.test_limits import READY as ARDUCOPTER_DEFAULTS


def test_a_vehicle_down_by_itself_hands_its_mail_back_and_the_drone_starts_no_task() -> None:
    """A failsafe or a pilot lands the vehicle under a flying plan: the stack must not go on to
    report a pickup (or a delivery) the vehicle never made, nor start the next mail."""
    async def scenario() -> tuple[FakeNode, DroneAgent, list[object]]:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.mail.take(MailOrder(id="first", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        agent.mail.take(MailOrder(id="next", pickup=[2, 4, 0], dropoff=[6, 1, 0], priority=1))
        later: list[object] = []
        for step in range(16):
            actions = agent.tick(step)
            if step == 3:  # taken up for its plan, then down by itself
                agent.vehicle.airborne = True
                vehicle.come_down()
            report = StepReport(step, agent.stack.executor.cell, (0, 0, 0), 0.0, False, 0.0)
            agent.on_step(report, actions)
            if step > 3:
                later += actions
            await asyncio.sleep(0)  # the mail desk reports on the loop
        try:
            agent.mail.take(MailOrder(id="refused", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
        except ProblemError as exc:
            later.append(exc)
        return node, agent, later

    node, agent, later = asyncio.run(scenario())
    why = "drone d1's vehicle came down by itself in [0, 0, 0]"
    assert statuses(node, "first") == [(MailStatus.ACCEPTED, ""), (MailStatus.STARTED, ""),
                                      (MailStatus.HANDED_BACK, why)]
    assert statuses(node, "next") == [(MailStatus.ACCEPTED, ""), (MailStatus.HANDED_BACK, why)]
    assert agent.mail.held() == []
    assert "came down" in agent.alarms["down"]
    kinds = {type(a).__name__ for a in later if not isinstance(a, Exception)}
    assert not kinds & {"GoTo", "MailStarted", "MailPickedUp", "MailDelivered"}, kinds
    assert "Completed" not in kinds  # the plan under way is not flown on: the vehicle is on the ground
    assert agent.stack.executor.cell == (0, 0, 0) and agent.stack.executor.trajectory is None
    told = [decode(p).body for k, p in node.puts if k == KEYS.plan("d1")]
    assert any(isinstance(b, PlanAnnounce) and b.grounded and b.trajectory.cells == ((0, 0, 0),) for b in told)
    refusal = [str(a) for a in later if isinstance(a, Exception)]
    assert refusal == ["drone d1 takes no mail: its vehicle came down by itself"]


def test_a_drone_whose_vehicle_waits_for_its_position_says_so_and_takes_no_mail() -> None:
    """ArduCopter SITL needs about 45 s from boot to its position estimate: the drone is a member
    meanwhile, says ``waiting_for_position``, refuses mail with the reason, and takes it once ready."""
    async def scenario() -> None:
        vehicle = vehicle_over_its_start()
        vehicle.estimate = False
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.tick(0)
        view = agent.state().vehicle
        assert view is not None and view.status == "waiting_for_position"
        assert "position estimate" in view.reason
        order = MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=5)
        try:
            agent.mail.take(order)
        except ProblemError as exc:
            assert "its vehicle is not ready: no position estimate" in str(exc)
        else:
            raise AssertionError("a drone whose vehicle has no position took mail")
        vehicle.estimate = True
        agent.tick(1)
        view = agent.state().vehicle
        assert view is not None and view.status == "ready"
        assert agent.mail.take(order)
        agent.tick(2)
        assert stack.protocol.state is not State.WAIT_FOR_TASK  # a task under way

    asyncio.run(scenario())


def test_a_lost_vehicle_is_its_drones_problem_and_back_in_a_held_cell_the_drone_carries_on() -> None:
    """The link goes silent mid-plan: the drone stays a member, raises vehicle_lost, hands back the mail
    it has not picked up, holds every cell its vehicle may be in (its answers say so) and takes no mail.
    The vehicle answers again, seen in one of those cells: the drone rests there and takes mail again."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 7, 0)})

    async def scenario() -> None:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, GeoFrame(ws), lambda: 1000.0)
        agent.mail.take(MailOrder(id="m", pickup=[4, 0, 0], dropoff=[6, 3, 0], priority=5))
        d2 = Trajectory.stationary((7, 7, 0), 0)
        for step in range(30):  # coordinate (d2 answers, then holds the plan), then fly the first steps
            if stack.executor.flying:
                break
            agent.tick(step)
            for _ in range(2):  # d2 answers the request, then holds the plan it brings
                for k, p in list(node.puts):
                    body = decode(p).body
                    if isinstance(body, ReqTraj) and k == KEYS.proto("all", "d1"):
                        reply: Message = CurrentTraj("d2", d2, body.task_id.core())
                    elif isinstance(body, Propose):
                        reply = PlanAck("d2", body.task_id.core(), d2)
                    else:
                        continue
                    agent._on_protocol(KEYS.proto("d1", "d2"), encode("d2", 1000.0, from_core(reply)))
                    node.puts.remove((k, p))
            vehicle.over(stack.executor.cell)
        assert stack.executor.flying
        agent.tick(step)
        plan = stack.protocol.trajectory
        assert plan is not None
        vehicle.over(stack.executor.cell)
        seen = stack.executor.cell
        agent.tick(step + 1)
        vehicle.lost = "vehicle 1 on udpin://127.0.0.1:14540: no HEARTBEAT for 3.1 s (timeout 3.0 s)"
        await asyncio.sleep(0)
        agent.tick(step + 2)
        await asyncio.sleep(0)
        assert agent.alarms["vehicle_lost"].startswith("vehicle_lost: vehicle 1 on udpin")
        assert statuses(node, "m")[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is lost")
        assert set(stack.protocol.holds()) >= set(plan.suffix_from(step + 2).cells) | {seen}
        asked = ReqForCurrentTraj(TaskId(step + 50, "d2", 9), "d2", Trajectory.stationary((7, 7, 0), step), ("d1",))
        node.puts.clear()
        agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, from_core(asked)))
        answer = to_core(decode(node.puts[-1][1]), "d2")
        assert isinstance(answer, CurrentTraj) and set(answer.holds) == set(stack.protocol.holds())
        with_mail = MailOrder(id="m2", pickup=[2, 2, 0], dropoff=[3, 5, 0], priority=5)
        try:
            agent.mail.take(with_mail)
        except ProblemError as exc:
            assert "its vehicle is lost" in str(exc)
        else:
            raise AssertionError("a drone whose vehicle is lost took mail")

        back = plan.cells[-2]  # it held on along its plan, and is seen there
        vehicle.lost = None
        vehicle.over(back, at=2.0)
        agent.tick(step + 3)
        assert "vehicle_lost" not in agent.alarms
        assert (stack.executor.cell, stack.protocol.location, stack.protocol.holds()) == (back, back, ())
        assert agent.mail.take(with_mail)

    asyncio.run(scenario())


def test_a_vehicle_back_outside_its_held_cells_leaves_its_drone_out_of_service() -> None:
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0)})

    async def scenario() -> None:
        vehicle = vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, GeoFrame(ws), lambda: 1000.0)
        agent.tick(0)
        vehicle.lost = "connection closed by the vehicle"
        agent.tick(1)
        vehicle.lost = None
        vehicle.over((5, 5, 0), at=2.0)  # in the air, far from its cell
        agent.tick(2)
        assert "not in a cell held for it" in agent.alarms["vehicle_lost"]
        assert stack.protocol.holds() != ()  # still held where it may be
        assert agent.mail.refusal is not None and "land it by hand" in agent.mail.refusal

    asyncio.run(scenario())


def test_the_flight_record_has_only_fresh_sightings_never_a_stale_or_lost_vehicle() -> None:
    """A cell is recorded at a sample only from a position reported since the previous one: a vehicle
    whose position stopped coming, or whose link is lost, leaves a gap (the audit counts it), never the
    last cell it was seen in (a killed ArduCopter SITL was recorded for 23 steps where it died)."""
    record, vehicle = io.StringIO(), vehicle_over_its_start()

    async def scenario() -> None:
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0,
                           record)
        for step in range(8):
            if step not in (3, 4):  # no new position at steps 3 and 4
                vehicle.at += 1.0
            vehicle.lost = "no HEARTBEAT for 3.0 s" if step >= 6 else None
            actions = agent.tick(step)
            agent.on_step(StepReport(step, stack.executor.cell, (0, 0, 0), 0.0, False, 0.0), actions)
            agent.on_sample(Sample(step, stack.executor.cell, (0, 0, 0), 0.0))
            await asyncio.sleep(0)

    asyncio.run(scenario())
    steps = [json.loads(line)["step"] for line in record.getvalue().splitlines()]
    assert steps == [0, 1, 2, 5]


def test_a_record_names_the_cells_passed_since_the_record_before_it() -> None:
    """Catching up, the vehicle crossed (1,0,0) and (2,0,0) over two samples, the first of which had no
    fresh position (a gap in the record): the next record names both, without the records' own cells."""
    record, vehicle = io.StringIO(), vehicle_over_its_start()
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0, record)
    agent.on_sample(Sample(0, (0, 0, 0), (0, 0, 0), 0.0, ((0, 0, 0),)))
    agent.on_sample(Sample(1, (1, 0, 0), (0, 0, 0), None, ((0, 0, 0), (1, 0, 0))))  # nothing fresh
    vehicle.over((3, 0, 0), at=vehicle.at + 1.0)
    agent.on_sample(Sample(2, (3, 0, 0), (3, 0, 0), 0.1, ((2, 0, 0), (3, 0, 0))))
    lines = [json.loads(line) for line in record.getvalue().splitlines()]
    assert [(r["step"], r["cell"], r.get("via")) for r in lines] == [
        (0, [0, 0, 0], None), (2, [3, 0, 0], [[1, 0, 0], [2, 0, 0]])]


def test_a_late_vehicle_is_recorded_where_it_was_when_its_sample_was_due() -> None:
    """A host sampling step 1 late saw the vehicle reach (2,0,0) after the sample was due: the record
    puts it in (1,0,0), the last cell reported by then, and (2,0,0) is passed on the way to the next
    record; recorded in (2,0,0), the next record passed (1,0,0) again, as if it went back."""
    record, vehicle = io.StringIO(), vehicle_over_its_start()
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0, record)
    agent.on_sample(Sample(0, (0, 0, 0), (0, 0, 0), 0.0, ((0, 0, 0),)))
    vehicle.over((2, 0, 0), at=vehicle.at + 1.0)
    agent.on_sample(Sample(1, (2, 0, 0), (2, 0, 0), None, ((0, 0, 0), (1, 0, 0))))
    vehicle.over((3, 0, 0), at=vehicle.at + 1.0)
    agent.on_sample(Sample(2, (3, 0, 0), (3, 0, 0), 0.1, ((1, 0, 0), (2, 0, 0), (3, 0, 0))))
    lines = [json.loads(line) for line in record.getvalue().splitlines()]
    assert [(r["step"], r["cell"], r.get("via")) for r in lines] == [
        (0, [0, 0, 0], None), (1, [1, 0, 0], None), (2, [3, 0, 0], [[2, 0, 0]])]


def _d1_with_mail(order: MailOrder) -> tuple[FakeNode, FakeVehicle, DroneStack, DroneAgent]:
    """d1's agent over its vehicle at its start, given ``order``."""
    node, vehicle = FakeNode(), vehicle_over_its_start()
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)
    agent.mail.take(order)
    return node, vehicle, stack, agent


def test_a_vehicle_later_than_lambda_holds_where_its_plan_ends_and_takes_no_task_until_on_time() -> None:
    """Peers plan with a margin of lambda for a vehicle's lateness: past it, the margin is gone. The
    drone plans nothing more, hands back the mail not on board, and every peer holds the rest of its
    plan; once its vehicle is where that plan ended, it takes tasks again."""
    async def scenario() -> tuple[FakeNode, DroneAgent, list[str]]:
        node, vehicle, stack, agent = _d1_with_mail(MailOrder(id="first", pickup=[3, 0, 0], dropoff=[5, 5, 0],
                                                              priority=9))
        seen: list[str] = []
        for step in range(40):
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), agent.tick(step))
            agent.vehicle.airborne = not seen[1:]
            if stack.executor.flying and stack.executor.cell != (0, 0, 0) and agent.late is None and not seen:
                agent.on_sample(Sample(step, stack.executor.cell, (0, 0, 0), None))  # still at the start
                seen.append(f"late: off since {stack.protocol.off_since}")
                with pytest.raises(ProblemError, match="its vehicle was not in"):
                    agent.mail.take(MailOrder(id="refused", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
            elif seen and stack.executor.trajectory is None and agent.late is not None:
                # Seen in the cell of the step sampled (lambda ago), not yet where the plan ended: still late.
                vehicle.over((2, 0, 0), at=vehicle.at + 1.0)
                agent.on_sample(Sample(step, (2, 0, 0), (2, 0, 0), 0.4))
                assert agent.late is not None and stack.executor.cell != (2, 0, 0)
                vehicle.over(stack.executor.cell, at=vehicle.at + 1.0)
                agent.vehicle.airborne = False  # landed there (SITL found a drone late for good once landed)
                agent.on_sample(Sample(step, stack.executor.cell, stack.executor.cell, 0.4))
                agent.vehicle.airborne = True
                seen.append(f"on time: off since {stack.protocol.off_since}")
                agent.mail.take(MailOrder(id="again", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
            await asyncio.sleep(0)
        return node, agent, seen

    node, agent, seen = asyncio.run(scenario())
    assert seen[0].startswith("late: off since ") and seen[0] != "late: off since None"
    assert seen[1:] == ["on time: off since None"]
    assert statuses(node, "first")[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is later than lambda")
    assert statuses(node, "again")[0] == (MailStatus.ACCEPTED, "")
    assert "late" not in agent.alarms


def test_a_late_vehicle_is_held_on_its_plan_from_the_last_step_it_was_seen_on_time() -> None:
    """Found over 128 agents on 2 cores: a process behind its boundaries saw its vehicle late only
    steps after it fell behind. Peers held the rest of its plan from then, not the cells the vehicle
    still had to fly through, and planned through them."""
    async def scenario() -> tuple[DroneStack, int, int]:
        _, _, stack, agent = _d1_with_mail(MailOrder(id="far", pickup=[7, 6, 0], dropoff=[0, 7, 0], priority=9))
        on_time: list[int] = []
        for step in range(60):
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), agent.tick(step))
            agent.vehicle.airborne = True
            if not stack.executor.flying or stack.executor.cell == (0, 0, 0):
                continue
            if len(on_time) < 2:
                agent.on_sample(Sample(step, stack.executor.cell, stack.executor.cell, 0.2))
                on_time.append(step)
            elif step >= on_time[-1] + WS.delta + 3:  # no sample since: the process was behind
                agent.on_sample(Sample(step, stack.executor.cell, (1, 0, 0), None))
                return stack, on_time[-1], step
            await asyncio.sleep(0)
        raise AssertionError("the plan never flew")

    stack, last_on_time, found_late = asyncio.run(scenario())
    assert stack.protocol.off_since == last_on_time < found_late - WS.delta - 1
    plan = stack.protocol.trajectory
    assert plan is not None
    assert set(plan.suffix_from(last_on_time - WS.delta - 1).cells) <= set(stack.protocol.holds())


def test_a_host_behind_its_boundaries_or_its_inbox_starts_no_task_and_keeps_the_mail(
        caplog: pytest.LogCaptureFixture) -> None:
    """Found over 128 agents on 2 cores: tasks started while the host was seconds behind made its vehicles
    later and its peers' news older, and drones braked into one cell. Behind by more than a quarter of tau,
    at a boundary or in the inbox, a drone waits; its mail stays its own, and it starts once caught up."""
    async def scenario() -> tuple[DroneAgent, list[str]]:
        _, _, stack, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        backlog = [WS.tau_s]  # the inbox is behind at the first boundary, the boundary itself at the second
        agent.backlog_s = lambda: backlog[0]
        seen: list[str] = []
        for step in range(3):
            actions = agent.tick(step)
            waiting = stack.protocol.state is State.WAIT_FOR_TASK
            seen.append("waits" if waiting else "starts")
            assert agent.alarms == {}  # healthy all along: the service keeps giving it mail
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.4 * WS.tau_s * (step == 0)),
                          actions)
            backlog[0] = 0.0
            await asyncio.sleep(0)
        return agent, seen

    agent, seen = asyncio.run(scenario())
    assert seen == ["waits", "waits", "starts"]
    assert "d1: the host is 1000 ms behind (bound 250 ms): no task starts" in caplog.text
    assert [m.id for m in agent.mail.listed()] == ["m"]


def test_a_host_starts_no_more_tasks_at_a_boundary_than_it_can_coordinate_within_its_bound(
        caplog: pytest.LogCaptureFixture) -> None:
    """Found over 128 agents on 2 cores: the 64 drones of a process, given mail at once, started 64 tasks at
    one boundary, before any lag showed, and the process fell seconds behind. A host whose messages take
    long to handle starts fewer tasks at a boundary; a drone past the host's share waits for the next
    boundary, its mail its own."""
    async def scenario() -> tuple[DroneAgent, list[str]]:
        _, _, stack, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        agent.alive = {"d1", "d2", "d3"}
        assert agent.budget.handling_s is None
        agent.budget.handled(0.03)  # 3 x 2 peers x 30 ms: one task fills the 250 ms bound
        agent.budget.started(0)  # another drone of the host took it at the first boundary
        seen: list[str] = []
        for step in range(2):
            actions = agent.tick(step)
            seen.append("waits" if stack.protocol.state is State.WAIT_FOR_TASK else "starts")
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), actions)
            await asyncio.sleep(0)
        return agent, seen

    agent, seen = asyncio.run(scenario())
    assert seen == ["waits", "starts"]
    assert "d1: the host started 1 task(s) at this boundary, all it may with 2 peers" in caplog.text
    assert [m.id for m in agent.mail.listed()] == ["m"]
    assert agent.alarms == {}


def test_a_host_measures_how_long_a_protocol_message_takes_to_handle() -> None:
    async def scenario() -> DroneAgent:
        _, _, _, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        asked = ReqForCurrentTraj(TaskId(50, "d2", 9), "d2", Trajectory.stationary((7, 7, 0), 0), ("d1",))
        agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, from_core(asked)))
        return agent

    agent = asyncio.run(scenario())
    assert agent.budget.handling_s is not None and agent.budget.handling_s > 0


def test_a_limit_set_lower_in_flight_puts_the_drone_out_of_its_bound_until_set_back() -> None:
    """Another ground station sets WPNAV_SPEED to 1 m/s in flight (the autopilot tells every one): lambda,
    derived from the workspace's limits, no longer holds. The drone is late at once, as a vehicle seen
    late is, and stays so at the end of its plan until the limit is set back."""
    async def scenario() -> tuple[FakeNode, list[str]]:
        node, vehicle, stack, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0],
                                                              priority=9))
        vehicle.parameters = dict(ARDUCOPTER_DEFAULTS)
        seen: list[str] = []
        for step in range(40):
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), agent.tick(step))
            agent.vehicle.airborne = True
            if stack.executor.flying and stack.executor.cell != (0, 0, 0) and not seen:
                seen.append(f"limits: {agent.limits_short}, late: {agent.late is not None}")
                vehicle.parameters["WPNAV_SPEED"] = 100.0
            elif seen and stack.executor.trajectory is None and len(seen) == 1:
                vehicle.over(stack.executor.cell, at=vehicle.at + 1.0)
                agent.on_sample(Sample(step, stack.executor.cell, stack.executor.cell, 0.1))
                seen.append(f"at its plan's end, set short: late {agent.late is not None}")
                vehicle.parameters["WPNAV_SPEED"] = 1000.0
            elif len(seen) == 2:
                vehicle.over(stack.executor.cell, at=vehicle.at + 1.0)
                agent.on_sample(Sample(step, stack.executor.cell, stack.executor.cell, 0.1))
                seen.append(f"set back: late {agent.late is not None}, alarm {'limits' in agent.alarms}")
            await asyncio.sleep(0)
        return node, seen

    node, seen = asyncio.run(scenario())
    assert seen == ["limits: None, late: False", "at its plan's end, set short: late True",
                    "set back: late False, alarm False"]
    assert statuses(node, "m")[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is later than lambda")


def test_a_limit_set_lower_in_flight_is_named_in_the_alarm() -> None:
    async def scenario() -> DroneAgent:
        _, vehicle, _, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        vehicle.parameters = {**ARDUCOPTER_DEFAULTS, "WPNAV_ACCEL": 100.0}
        agent.vehicle.airborne = True
        agent.on_step(StepReport(0, (0, 0, 0), None, 0.0, False, 0.0), agent.tick(0))
        return agent

    agent = asyncio.run(scenario())
    assert agent.alarms["limits"] == ("limits: WPNAV_ACCEL 100 gives 1, under the workspace's vehicle.accel_m_s2 "
                                      f"{WS.vehicle.accel_m_s2:g}")
    assert agent.late is not None and "WPNAV_ACCEL 100 gives 1" in agent.late


@pytest.mark.parametrize("late_by", [-0.01, 0.01])
def test_a_setpoint_sent_later_than_lambda_into_its_step_makes_the_vehicle_late_at_once(late_by: float) -> None:
    """Found over 128 agents on 2 cores: a host seconds behind sent each setpoint seconds late, and sampled
    its vehicles as late: they were judged seconds after peers planned around them. A vehicle sent to its
    next cell later than lambda into the step cannot be there in time: it is late at that boundary."""
    async def scenario() -> tuple[DroneStack, DroneAgent]:
        _, _, stack, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        for step in range(40):
            before = stack.executor.cell
            actions = agent.tick(step)
            agent.vehicle.airborne = True
            if stack.executor.flying and stack.executor.cell != before:
                late = WS.lateness_s + late_by
                agent.on_step(StepReport(step, stack.executor.cell, before, 0.0, False, late, 0, before), actions)
                return stack, agent
            agent.on_step(StepReport(step, stack.executor.cell, before, 0.0, False, 0.0, 0, before), actions)
            await asyncio.sleep(0)
        raise AssertionError("the plan never moved")

    stack, agent = asyncio.run(scenario())
    assert (agent.late is not None) is (late_by > 0)
    assert (stack.protocol.off_since is not None) is (late_by > 0)
    if late_by > 0:
        assert agent.late is not None and "later than lambda" in agent.late


def test_a_vehicle_still_on_the_ground_when_its_plan_moves_on_is_late() -> None:
    """Found over 128 agents on 2 cores: d75's vehicle had not taken off when its plan left its cell, and
    only a vehicle in the air was judged. Its plan flew on, peers planned through the cell it sat under,
    and d93 came down the column into it. A climb longer than the lead is late like any other."""
    async def scenario() -> tuple[DroneStack, DroneAgent]:
        _, _, stack, agent = _d1_with_mail(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        for step in range(40):
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), agent.tick(step))
            assert not agent.vehicle.airborne  # never taken off
            if stack.executor.flying and stack.executor.cell != (0, 0, 0):
                agent.on_sample(Sample(step, stack.executor.cell, (0, 0, 0), None))  # on the ground at its start
                return stack, agent
            await asyncio.sleep(0)
        raise AssertionError("the plan never moved")

    stack, agent = asyncio.run(scenario())
    assert agent.late is not None and "late" in agent.alarms
    assert stack.protocol.off_since is not None
