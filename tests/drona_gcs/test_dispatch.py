"""The fleet's one rule for which drone takes a mail (used by `drona mail` and the service)."""

from __future__ import annotations

import asyncio

from drona_gcs.dispatch import Candidate, choose_drone
from fleet.transport.fleet_client import FleetClient
from fleet.transport.keys import FleetKeys
from fleet.transport.wire import DroneState, Health, MailAck, MailOrder

PICKUP = (5, 5, 0)


def test_no_candidate_no_drone() -> None:
    assert choose_drone([], PICKUP) is None


def test_preference_is_healthy_then_least_held_then_idle_then_nearest_then_name() -> None:
    near, far = (5, 4, 0), (0, 0, 0)
    ranked = [
        Candidate("h-near-idle", near, held=0, busy=False),
        Candidate("g-far-idle", far, held=0, busy=False),
        Candidate("f-near-busy", near, held=0, busy=True),
        Candidate("e-near-holding", near, held=1, busy=False),
        Candidate("d-sick", near, held=0, busy=False, healthy=False),
    ]
    for i in range(len(ranked)):
        assert choose_drone(ranked[i:], PICKUP) == ranked[i].drone
    twins = [Candidate("b", near, 0, False), Candidate("a", near, 0, False)]
    assert choose_drone(twins, PICKUP) == "a"


def test_the_distance_is_the_callers() -> None:
    walls = {"x": 3, "y": 30}
    candidates = [Candidate("x", (9, 9, 0), 0, False), Candidate("y", (5, 4, 0), 0, False)]
    cells = {c.cell: c.drone for c in candidates}
    assert choose_drone(candidates, PICKUP, lambda a, b: walls[cells[a]]) == "x"


def test_drona_mail_offers_a_mail_down_the_ranking_while_drones_refuse() -> None:
    """Flown on ArduCopter SITL with one clock off: every drone had a clock alarm (the others', about
    it), so the ranking put the drone off first, and `drona mail` reported its refusal as the answer.
    The next drone is asked while they refuse; if every drone does, the answer names each refusal."""
    orders: list[str] = []

    class Fleet(FleetClient):
        async def wait_for_drones(self, timeout_s: float) -> dict[str, DroneState]:
            sick = Health(ok=False, alarms=["clock skew"])
            return {d: DroneState(drone=d, step=0, cell=[i, 0, 0], mode="WaitForTaskRequest", phase="idle",
                                  landed=True, health=sick) for i, d in enumerate(("d3", "d1", "d2"))}

        async def assign(self, drone: str, order: MailOrder, timeout_s: float = 2.0) -> MailAck:
            orders.append(drone)
            takes = drone in accepting
            return MailAck(id=order.id, drone=drone, accepted=takes, reason="" if takes else f"{drone} is off")

    order = MailOrder(id="m", pickup=[0, 0, 0], dropoff=[3, 3, 0], priority=1)
    fleet = Fleet(None, FleetKeys("t"), "test")  # type: ignore[arg-type]
    accepting = {"d2"}
    ack = asyncio.run(fleet.dispatch(order, None, 1.0))
    assert ack.accepted and ack.drone == "d2" and orders == ["d3", "d1", "d2"]
    accepting, orders[:] = set(), []
    ack = asyncio.run(fleet.dispatch(order, None, 1.0))
    assert not ack.accepted and orders == ["d3", "d1", "d2"]
    assert ack.reason == "every drone refused it (d3: d3 is off; d1: d1 is off; d2: d2 is off)"
