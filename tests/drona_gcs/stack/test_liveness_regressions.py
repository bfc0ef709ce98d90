"""Regressions found by the systematic tester's sweeps, replayed as small scenarios over the production
machines: whole :class:`~drona_gcs.stack.drone.DroneStack` fleets (the task planner, the protocol, the
executor and the battery monitor) with the tester's battery model, or the task planner alone.
"""

from __future__ import annotations

from collections.abc import Mapping

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import DroneAction, DroneStack, StackConfig, walled_behind, yield_spot
from drona_gcs.stack.mail import GoTo, MailAction, MailDelivered, MailPlanner, MailRequest, Phase
from drona_gcs.stack.messages import Message
from drona_gcs.stack.protocol import Broadcast, Grounded, Send
from drona_gcs.workspace import Cell, Workspace

#: A corridor closed by a charger: drop-off (0, 0), (1, 0), the low drone in (2, 0) beside a pocket (2, 1),
#: the drone with mail on board in (3, 0), the charger (4, 0).
CORRIDOR = Workspace.build(size=(5, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0), (3, 1, 0), (4, 1, 0)}),
                           charging_stations=((4, 0, 0),), drones={"carrier": (3, 0, 0), "low": (2, 0, 0)})
MAIL = MailRequest("m0", pickup=(3, 0, 0), dropoff=(0, 0, 0), priority=8)
MODEL = BatteryModel()


def fly_fleet(levels: Mapping[str, float], steps: int, ws: Workspace = CORRIDOR,
              mail: MailRequest = MAIL) -> tuple[dict[str, list[DroneAction]], dict[str, float]]:
    """The fleet of ``ws`` (the corridor's), ``carrier`` with ``mail``, every message delivered at once;
    batteries drain and charge as the systematic tester's world does. What each drone did, and its
    lowest battery level."""
    config = StackConfig(ws, SafePlanner(ws), MODEL)
    stacks = {d: DroneStack(d, config, dict(ws.drones)) for d in ws.drones}
    stacks["carrier"].assign(mail)
    level, lowest = dict(levels), dict(levels)
    done: dict[str, list[DroneAction]] = {d: [] for d in stacks}
    inbox: list[tuple[str, Message]] = []
    down: set[str] = set()

    def post(sender: str, actions: list[DroneAction]) -> None:
        done[sender] += actions
        for action in actions:
            if isinstance(action, Send):
                inbox.append((action.to, action.message))
            elif isinstance(action, Broadcast):
                inbox.extend((d, action.message) for d in stacks if d != sender)
            elif isinstance(action, Grounded):  # the runtime announces it: held for good
                down.add(sender)
                for peer in set(stacks) - {sender}:
                    post(peer, stacks[peer].peer_down(sender, action.trajectory.last))

    for step in range(steps):
        for drone, stack in stacks.items():
            if drone not in down:
                level[drone] = _after_step(stack, level[drone], ws)
                lowest[drone] = min(lowest[drone], level[drone])
            post(drone, stack.step(step, level[drone], stack.executor.cell, may_plan=drone not in down))
        while inbox:
            to, message = inbox.pop(0)
            post(to, stacks[to].receive(message))
    return done, lowest


def _after_step(stack: DroneStack, level: float, ws: Workspace) -> float:
    """A step's battery, as the tester's world has it: charging on a charger, nothing landed, else drained."""
    if stack.mail.phase is Phase.CHARGING and stack.executor.cell in ws.charging_stations:
        return min(100.0, level + MODEL.charge_per_step)
    return level if stack.landed else max(0.0, level - MODEL.drain_per_step)


def test_a_low_drone_asked_to_make_way_by_the_drone_walling_its_charger_in_makes_way() -> None:
    """Found by the systematic tester (sweep 30341: 5 drones, seed 91011): a drone with mail on board
    rested between a dead-end charger and a low drone that waited on the drop-off it had just flown, for
    that charger. Each leg found no plan through the other, and asked its way clear; the carrier had
    nowhere to go, and the low drone could not afford the way off and the way back to the charger, so it
    went to charge instead: through the carrier, for good. The mail on board was never delivered. The
    charger is reached only once the low drone has left; so it leaves with what it has, keeping no energy
    for a charger it cannot reach, as a drone whose battery reaches no charger does. The floor holds."""
    # 6 steps of flight to the charger, 5 to the pocket and 7 on from there (each leg's 4 lead and first steps in)
    level = MODEL.safe_threshold + 8 * MODEL.drain_per_step
    done, lowest = fly_fleet({"carrier": 100.0, "low": level}, 80)
    assert MailDelivered(MAIL) in done["carrier"]
    assert lowest["low"] >= MODEL.safe_threshold


#: A dead-end charger (4, 0) with a charged drone on it; the drone with mail on board rests in (3, 0), its
#: only way out, beside a pocket (3, 1); the drop-off (1, 0) and a parking cell (0, 0) down the corridor.
DEAD_END = Workspace.build(size=(5, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0), (2, 1, 0), (4, 1, 0)}),
                           charging_stations=((4, 0, 0),), parking=((0, 0, 0),),
                           drones={"carrier": (3, 0, 0), "charged": (4, 0, 0)})
DEAD_END_MAIL = MailRequest("m2", pickup=(3, 0, 0), dropoff=(1, 0, 0), priority=6)


def test_a_drone_walling_in_the_charger_it_waits_for_makes_way_for_the_drone_on_it() -> None:
    """Found by the systematic tester (sweep 30362 with --partitions 1 --crashes 1: 5 drones, seed
    561331): a drone too low to fly its mail before charging rested on the only way out of a dead-end
    charger a charged drone rested on. That one's legs to parking found no plan and asked nothing (legs
    to park waited): each waited for the other for good. A drone leaving a charger asks its way clear.
    The mail is delivered, and the floor holds."""
    level = MODEL.safe_threshold + 12 * MODEL.drain_per_step
    done, lowest = fly_fleet({"carrier": level, "charged": 100.0}, 120, DEAD_END, DEAD_END_MAIL)
    assert MailDelivered(DEAD_END_MAIL) in done["carrier"]
    assert lowest["carrier"] >= MODEL.safe_threshold


def test_only_a_charger_whose_every_way_the_asker_walls_in_for_good_counts_as_behind_it() -> None:
    """The chargers a drone asked to make way reaches only through the asker's cell, where the asker has
    nowhere to make way to in turn: with a side pocket for the asker, it could step aside, and does not
    wall the charger in."""
    here, asker, taken = (2, 0, 0), (3, 0, 0), {(3, 0, 0)}
    assert walled_behind(CORRIDOR, here, asker, taken, frozenset()) == frozenset({(4, 0, 0)})
    assert yield_spot(CORRIDOR, asker, frozenset({(3, 0, 0), (4, 0, 0)}), {here}) is None
    pocket = Workspace.build(size=(5, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0), (4, 1, 0)}),
                             charging_stations=((4, 0, 0),))
    assert walled_behind(pocket, here, asker, taken, frozenset()) == frozenset()  # it may step into (3, 1)
    around = Workspace.build(size=(5, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0)}),
                             charging_stations=((4, 0, 0),))
    assert walled_behind(around, here, asker, taken, frozenset()) == frozenset()  # a way around it
    lost: frozenset[Cell] = frozenset({(3, 1, 0)})  # the pocket taken by a vehicle down: nowhere to go again
    assert walled_behind(pocket, here, asker, taken | lost, lost) == frozenset({(4, 0, 0)})


def cut_off_urgent_mail(taken: frozenset[Cell]) -> MailPlanner:
    """A planner whose leg to its most urgent mail's pickup was cut off while drones rested on ``taken``."""
    mp = MailPlanner((0, 0, 0), (), (), lambda a, b: abs(a[0] - b[0]) + abs(a[1] - b[1]))
    mp.assign(URGENT)
    mp.assign(LATER)
    assert goto(mp.decide(0, 100.0, taken)).goal == URGENT.pickup
    mp.leg_failed(1, cut_off=True)
    return mp


URGENT = MailRequest("urgent", pickup=(2, 0, 0), dropoff=(3, 0, 0), priority=4)
LATER = MailRequest("later", pickup=(0, 2, 0), dropoff=(0, 3, 0), priority=3, seq=1)


def goto(actions: list[MailAction]) -> GoTo:
    return next(a for a in actions if isinstance(a, GoTo))


def test_mail_cut_off_comes_first_again_once_a_drone_resting_then_has_moved() -> None:
    """Found by the systematic tester (sweep 30353 with --skews 1: 5 drones, seed 318124): a drone on a
    dead-end charger was walled in by a peer resting on the only way out; its leg to the most urgent
    pickup was cut off, and that mail was put after the rest. The peer flew on; with the way open, the
    drone, which had not moved, still started less urgent mail first (monitor (c)). Cut off is measured
    against the drones resting then: once they rest elsewhere, the mail ranks as any other again."""
    walling: frozenset[Cell] = frozenset({(1, 0, 0)})
    assert goto(cut_off_urgent_mail(walling).decide(5, 100.0, walling)).goal == LATER.pickup
    moved: frozenset[Cell] = frozenset({(5, 5, 0)})
    assert goto(cut_off_urgent_mail(walling).decide(5, 100.0, moved)).goal == URGENT.pickup
