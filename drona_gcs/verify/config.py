"""What the tester's world is made of: the faults it may see, the fleet's configuration (a rolling
upgrade's among it), and random scenarios the service would accept."""

from __future__ import annotations

import functools
import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from drona_gcs.errors import ProblemError
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import leg_overhead
from drona_gcs.stack.mail import MailPlanner, MailRejected, MailRequest
from drona_gcs.workload import random_workspace
from drona_gcs.workspace import Cell, Workspace


@dataclass(frozen=True)
class Faults:
    """How many of each fault of the field a run may see (each at any point the schedule picks)."""

    duplicates: int = 2  #: a message delivered twice
    cancels: int = 1  #: a mail cancelled by its sender (taken back only while it waits in a queue)
    downs: int = 1  #: a vehicle that comes down by itself: its mail is handed back (or lost, on board)
    #: agents that crash (the vehicle holds its cell in the air; messages to it are lost; its peers
    #: see it leave) and may restart there later (its peers see it join); none unless asked for
    crashes: int = 0
    #: a drone cut off from the rest for a while (messages across the cut lost; each side sees the
    #: other leave, and join again once it heals, within PARTITION_STEPS); none unless asked for
    partitions: int = 0
    #: a drone whose clock goes beyond the fleet's bound: each drone's clock check says so at a point the
    #: schedule picks (to the drone: its clock is off; to a peer: that drone's is), and once every drone
    #: knows, its steps keep within Delta of the others' shifted by Delta + SKEW_STEPS, ahead or behind;
    #: none unless asked for
    skews: int = 0

    @classmethod
    def none(cls) -> Faults:
        """The paper's model: none of the field's faults."""
        return cls(0, 0, 0, 0)


@dataclass(frozen=True)
class Upgrade:
    """The configuration of the mixed fleet's last drone, as during a rolling upgrade."""

    extra_lead: int = 2  #: lead steps more than the others' (see :func:`model_lead`)
    low_mark: float = 35.0
    recharged_mark: float = 90.0


UPGRADE = Upgrade()


MODEL_CLIMB_STEPS = 2  #: a landed model drone's take-off before its plan starts (one in the air needs none)


def model_hover_lead(delta: int, max_delay: int) -> int:
    """Lead steps of the model's drones in the air: the stack's default (Delta + 1), and at least a
    plan's round trip to be held by every peer (its proposal and the acks, ``max_delay`` steps each)
    and a step, so that a plan is never dropped for the model's network alone."""
    return max(delta + 1, 2 * max_delay + 1)


def model_lead(delta: int, max_delay: int) -> int:
    """Lead steps of the model's landed drones, which climb first."""
    return model_hover_lead(delta, max_delay) + MODEL_CLIMB_STEPS


PARTITION_STEPS = 20  #: a partition heals within this many steps of the slowest clock
VERDICT_STEPS = 2  #: every clock check finds a clock off within this many steps of the slowest clock
MAX_DRAWS = 1000  #: random draws of a mail the service accepts, before giving up


@dataclass(frozen=True)
class WorldConfig:
    workspace: Workspace
    drones: tuple[str, ...]
    starts: tuple[Cell, ...]
    requests: tuple[MailRequest, ...]
    assignees: tuple[str, ...]
    delta: int
    bugs: frozenset[str] = frozenset()
    battery: BatteryModel = field(default_factory=BatteryModel)
    initial_battery: tuple[float, ...] = ()  #: per drone; empty: all full
    max_delay: int = 2
    liveness_steps: int = 120  #: every mail delivered within this many steps after the last one arrives
    faults: Faults = field(default_factory=Faults)
    mixed: bool = True  #: the last drone runs another configuration, as during a rolling upgrade

    def __deepcopy__(self, memo: dict[int, object]) -> WorldConfig:
        return self


def make_world_config(workspace: Workspace, drones: int, requests: int, delta: int, seed: int,
                      bugs: frozenset[str] = frozenset(), **options: object) -> WorldConfig:
    """Drones at the workspace's starts (random free cells for the rest) and random mail."""
    rng = random.Random(seed)
    region = sorted(workspace.main_region)
    ids = list(workspace.drones)[:drones]
    starts = [workspace.drones[d] for d in ids]
    spare = [c for c in region if c not in starts and c not in workspace.charging_stations
             and c not in workspace.parking]
    while len(ids) < drones:
        cell = rng.choice(spare)
        spare.remove(cell)
        ids.append(f"d{len(ids)}")
        starts.append(cell)
    # Mail never goes to a parking cell or charger: a drone may rest there for good.
    spots = set(workspace.parking) | set(workspace.charging_stations)
    pickups = [c for c in list(workspace.pickups) or region if c not in spots]
    dropoffs = [c for c in list(workspace.dropoffs) or region if c not in spots]
    max_delay = options.get("max_delay", WorldConfig.max_delay)
    assert isinstance(max_delay, int)
    extra_lead = model_lead(delta, max_delay) - model_lead(delta, WorldConfig.max_delay)
    model = options.get("battery") or _battery_for(workspace, extra_lead)
    assert isinstance(model, BatteryModel)
    options = {**options, "battery": model}
    accepts = _service_check(workspace, model, model_lead(delta, max_delay))
    mail = []
    for i in range(requests):
        for _ in range(MAX_DRAWS):
            pickup = rng.choice(pickups)
            request = MailRequest(f"m{i}", pickup, rng.choice([c for c in dropoffs if c != pickup]),
                                  rng.randint(0, 9), seq=i)
            if accepts(request):
                break
        else:
            raise ProblemError(f"no mail a charged drone can fly in {MAX_DRAWS} draws: grid too large for the battery")
        mail.append(request)
    assignees = tuple(ids[i % len(ids)] for i in range(requests))
    # Batteries start part-charged, so charging and the energy checks are exercised.
    levels = tuple(_initial_level(workspace, start, model, rng) if workspace.charging_stations else 100.0
                   for start in starts)
    # Generous enough for a drone's share of the mail, a charge and the detours of a busy grid. The
    # share is of the drones left flying once the faults took theirs: the service gives their mail on.
    faults = options.get("faults", Faults())
    assert isinstance(faults, Faults)
    per_drone = -(-requests // max(1, len(ids) - faults.crashes - faults.downs))
    span = workspace.nx + workspace.ny + workspace.nz
    liveness = 8 * span * (per_drone + 1) + 100
    defaults: dict[str, object] = {"initial_battery": levels, "liveness_steps": liveness}
    return WorldConfig(workspace, tuple(ids), tuple(starts), tuple(mail), assignees, delta, bugs,
                       **{**defaults, **options})  # type: ignore[arg-type]


def _battery_for(workspace: Workspace, extra_lead: int = 0) -> BatteryModel:
    """A battery that flies across the workspace and back, with its margin: the default one where it
    does (8x8, 16x16), a slower drain on larger grids (32x32), where no mail would be affordable.
    ``extra_lead``: lead steps above those of the default network (max_delay 2), which each of a mail's
    three legs takes too: the battery lasts that much longer, or a slower network would leave no mail
    affordable on 16x16."""
    default = BatteryModel()
    need = 2 * (workspace.nx + workspace.ny + workspace.nz - 3) + default.margin_steps
    affordable = default.steps_affordable(95.0)
    base = default if need <= affordable else _exact_drain(default.drain_per_step * affordable / need)
    if extra_lead <= 0:
        return base
    # Counted at the mixed fleet's lowest recharge mark; half a step more, as steps_affordable rounds down.
    steps = base.steps_affordable(UPGRADE.recharged_mark) + 3 * extra_lead
    return _exact_drain((UPGRADE.recharged_mark - default.safe_threshold) / (steps + 0.5))


#: drains are whole multiples of this (a power of two), at most that much below the one asked for
DRAIN_QUANTUM = 2.0**-20


def _exact_drain(drain: float) -> BatteryModel:
    """A battery draining ``drain`` a step, rounded down to a multiple of :data:`DRAIN_QUANTUM`: every level
    the world reaches (100, less drains, plus whole charges) is then exact in floating point, and a drone
    the planner lets fly exactly to the threshold does not end a rounding error below it."""
    return BatteryModel(drain_per_step=math.floor(drain / DRAIN_QUANTUM) * DRAIN_QUANTUM)


def _service_check(workspace: Workspace, model: BatteryModel, lead: int) -> Callable[[MailRequest], bool]:
    """The service's energy check: it takes only mail that a drone charged at a station can fly,
    whichever configuration it runs (see :data:`UPGRADE`)."""
    chargers = workspace.charging_stations
    to = functools.lru_cache(maxsize=None)(workspace.distances_from)

    def distance(a: Cell, b: Cell) -> int:
        return to(b).get(a, 10**6)

    def accepts(request: MailRequest) -> bool:
        for recharged, steps in ((95.0, lead), (UPGRADE.recharged_mark, lead + UPGRADE.extra_lead)):
            planner = MailPlanner(chargers[0], chargers, workspace.parking, distance, model,
                                  recharged_level=recharged, leg_overhead=leg_overhead(steps))
            planner.assign(request)
            if any(isinstance(a, MailRejected) for a in planner.decide(0, recharged, ())):
                return False
        return True

    return accepts if chargers else lambda request: True


def _initial_level(workspace: Workspace, start: Cell, model: BatteryModel, rng: random.Random) -> float:
    """Part-charged, so charging and the energy rules are exercised: enough to reach the second
    nearest charger with the margin to spare, plus up to 20 points."""
    far = workspace.distances_from(start)
    ways = sorted(far.get(c, 0) for c in workspace.charging_stations)
    reach = ways[min(1, len(ways) - 1)] if ways else 0
    floor = model.safe_threshold + (reach + model.margin_steps) * model.drain_per_step
    return float(min(100, round(floor) + 1 + rng.randint(0, 20)))


def tester_workspace(width: int, height: int, layers: int, obstacle_ratio: float, seed: int,
                     drones: int) -> Workspace:
    """A random grid for the tester, with two chargers and a parking cell per drone on its rim."""
    rough = random_workspace(width, height, random.Random(seed), obstacle_ratio, layers)
    free = sorted(rough.main_region)
    rim = [c for c in free if c[0] in (0, width - 1) or c[1] in (0, height - 1)] or free

    def nearest(target: Cell, pool: list[Cell]) -> Cell:
        return min(pool, key=lambda c: (abs(c[0] - target[0]) + abs(c[1] - target[1]) + c[2], c))

    chargers: list[Cell] = []
    parking: list[Cell] = []

    def usable(cell: Cell, group: list[Cell]) -> bool:
        """Drones resting on the group and ``cell`` must not cut the grid."""
        return cell not in chargers and cell not in parking and not rough.cells_cut_off_by([*group, cell])

    for corner in ((0, 0, 0), (width - 1, height - 1, 0)):
        chargers.append(nearest(corner, [c for c in rim if usable(c, chargers)]))
    for i in range(drones):
        pool = [c for c in rim if usable(c, parking) and not rough.cells_cut_off_by([*parking, *chargers, c])]
        if not pool:
            break
        parking.append(pool[(i * len(pool)) // drones])
    return Workspace.build(size=rough.size, obstacles=rough.obstacles, charging_stations=tuple(chargers),
                           parking=tuple(parking), name=f"tester-{width}x{height}x{layers}-{seed}")
