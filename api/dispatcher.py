"""The dispatcher: applies :mod:`api.dispatch`'s decisions through the store and the gateway.

It is the gateway's :class:`~api.gateway.FleetListener` and a commit listener of
the store. Fleet events land in an inbox; one task (:meth:`Dispatcher.run`) takes
them, gives up on mails past their deadline and hands waiting mail to drones with
room. It sleeps until something happens (an inbox item, a commit, a drone state)
or until the next deadline, whichever is first.

Every status change goes through the store first (durably); only then is a
drone told. A crash between the two leaves a mail ``assigned`` that no drone
mentions, which its deadline requeues.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable, Coroutine

from pydantic import TypeAdapter

from api import dispatch
from api.dispatch import Assignment, Decision, InFlight, Requeue, Waiting
from api.errors import ApiError, AssignRefused, IllegalTransition, MailNotFound, StoreError
from api.events import EventBus
from api.gateway import DroneView, FleetGateway, MailOrder, MailStatusReport
from api.lifecycle import FINAL, IN_FLIGHT, Status
from api.settings import ApiSettings
from api.store import Change, MailRecord, Store
from drona_gcs.workspace import Cell

log = logging.getLogger(__name__)
STORE_RETRY_S = 1.0  #: after the database failed, how long a dispatch round waits to try again
_DRONE_JSON = TypeAdapter(DroneView)
_Inbox = MailStatusReport | str  # a report, or the id of a lost drone


class Dispatcher:
    def __init__(self, store: Store, gateway: FleetGateway, distance: Callable[[Cell, Cell], int],
                 bus: EventBus, settings: ApiSettings, clock: Callable[[], float] = time.monotonic) -> None:
        self.store = store
        self.gateway = gateway
        self.distance = distance
        self.bus = bus
        self.settings = settings
        self.clock = clock
        self.in_flight: dict[str, InFlight] = {}
        self.queued = 0
        self._excluded: dict[str, dict[str, float]] = {}  # mail -> drone -> until
        self._rejections: dict[str, dict[str, int]] = {}  # mail -> drone -> times it rejected the mail
        self._inbox: list[_Inbox] = []
        self._wake = asyncio.Event()
        self._idle = asyncio.Event()  # set while asleep with nothing under way
        self._sending = 0  # exchanges with drones under way
        self._tasks: asyncio.TaskGroup | None = None
        self.paused = False  #: the operator paused the fleet: no mail is handed out
        self.held: set[str] = set()  #: drones the operator recalled or landed: handed nothing until resumed
        self.gone: set[str] = set()  #: drones lost and not back: their mail waits for them (no deadline)
        #: mail a drone started and was cleared to take on board: held as that drone's through a loss
        self.cleared: set[str] = set()
        #: cleared mail whose drone was lost since: a restarted agent forgets it, though its vehicle may carry it
        self.cleared_when_lost: set[str] = set()

    # ------------------------------------------------------- listeners
    def on_drone_state(self, view: DroneView) -> None:
        back = view.id in self.gone  # its mail gets a deadline from now: it sends again what we missed
        self.gone.discard(view.id)
        deadline = self.clock() + self.settings.assign_timeout_s
        for mail_id, held in self.in_flight.items():
            if held.drone == view.id and (back or view.mentions(mail_id)):
                self.in_flight[mail_id] = InFlight(mail_id, held.drone, held.status, deadline)
        self.bus.publish("drone", lambda: _DRONE_JSON.dump_json(view).decode())
        self._poke()

    def on_drone_lost(self, drone: str) -> None:
        self._inbox.append(drone)
        self.bus.publish("drone_lost", lambda: json.dumps({"id": drone}))
        self._poke()

    def on_mail_status(self, report: MailStatusReport) -> None:
        self._inbox.append(report)
        self._poke()

    def on_commit(self, change: Change) -> None:
        record = change.record
        if change.before is Status.QUEUED:
            self.queued -= 1
        if record.status is Status.QUEUED:
            self.queued += 1
        if record.status in IN_FLIGHT and record.drone is not None:
            deadline = self.clock() + self.settings.assign_timeout_s
            self.in_flight[record.id] = InFlight(record.id, record.drone, record.status, deadline)
        else:
            self.in_flight.pop(record.id, None)
        if record.status is not Status.ASSIGNED:
            self.cleared.discard(record.id)
            self.cleared_when_lost.discard(record.id)
        if record.status in FINAL:
            self._excluded.pop(record.id, None)
            self._rejections.pop(record.id, None)
        self._poke()

    def _poke(self) -> None:
        self._idle.clear()
        self._wake.set()

    async def idle(self) -> None:
        """Until the dispatcher has taken in every event so far and has nothing under way (for tests)."""
        await self._idle.wait()

    # ------------------------------------------------------------ loop
    def resume(self) -> None:
        """Take up where the last run stopped: mails held by drones get a fresh deadline.

        Called before the store's writer starts, so that no commit falls between the count and
        the commit listener."""
        deadline = self.clock() + self.settings.assign_timeout_s
        for record in self.store.with_status(IN_FLIGHT):
            if record.drone is not None:
                self.in_flight[record.id] = InFlight(record.id, record.drone, record.status, deadline)
                if record.status is Status.ASSIGNED:  # it may have been cleared before: held as the drone's
                    self.cleared.add(record.id)
        self.queued = self.store.count(Status.QUEUED)
        log.info("resumed: %d mail(s) queued, %d held by drones", self.queued, len(self.in_flight))

    async def run(self, tasks: asyncio.TaskGroup) -> None:
        """The dispatch loop; exchanges with drones run as tasks of ``tasks`` so that none holds it up."""
        self._tasks = tasks
        while True:
            await self._sleep()
            try:
                await self._round()
            except StoreError as exc:  # the database failed: the round is tried again, its reports kept
                log.error("dispatch: %s; trying again in %g s", exc, STORE_RETRY_S)
                await asyncio.sleep(STORE_RETRY_S)
                self._poke()

    async def _round(self) -> None:
        while self._inbox:  # each report leaves the inbox once taken in
            item = self._inbox[0]
            await (self._lost(item) if isinstance(item, str) else self._report(item))
            self._inbox.pop(0)
        heard = [m for m in self.in_flight.values() if m.drone not in self.gone]
        await self._decide(dispatch.expired(heard, self.clock(), self.cleared_when_lost))
        await self._assign_round()

    async def _sleep(self) -> None:
        """Until woken, or the next deadline (an in-flight mail's, or a refusal's end)."""
        if not self._wake.is_set():
            if self._sending == 0:
                self._idle.set()
            self._current_exclusions()  # drops the ended ones
            times = [m.deadline for m in self.in_flight.values() if m.drone not in self.gone]
            times += [t for drones in self._excluded.values() for t in drones.values()]
            delay = min(times) - self.clock() if times else None
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(delay):
                    await self._wake.wait()
        self._wake.clear()

    # ------------------------------------------------------ assignment
    def hold(self, *, paused: bool | None = None, drone: str | None = None, held: bool = True) -> None:
        """The operator's commands, as far as handing out mail goes: the fleet paused or not, a drone
        held or not."""
        if paused is not None:
            self.paused = paused
        if drone is not None:
            (self.held.add if held else self.held.discard)(drone)
        self._poke()

    async def _assign_round(self) -> None:
        if self.queued <= 0 or self.paused:
            return
        load: dict[str, int] = {}
        for held in self.in_flight.values():
            load[held.drone] = load.get(held.drone, 0) + 1
        free = [s for s in dispatch.slots(self.gateway.drones(), load, self.settings.per_drone)
                if s.drone not in self.held]
        if not free:
            return
        excluded = self._current_exclusions()
        records = self.store.waiting(sum(s.free for s in free) + len(excluded))
        waiting = [Waiting(r.id, r.pickup, r.priority, r.seq) for r in records]
        chosen = dispatch.assign(waiting, free, self.distance, excluded)
        by_id = {r.id: r for r in records}
        await asyncio.gather(*(self._hand_over(a, by_id[a.mail_id]) for a in chosen))

    async def _hand_over(self, choice: Assignment, record: MailRecord) -> None:
        """Assign durably, then tell the drone (in the background)."""
        try:
            await self.store.transition(choice.mail_id, Status.ASSIGNED, drone=choice.drone,
                                        only_from=frozenset({Status.QUEUED}))
        except (IllegalTransition, MailNotFound) as exc:  # cancelled meanwhile
            log.info("not assigning: %s", exc)
            return
        order = MailOrder(record.id, record.pickup, record.dropoff, record.priority, record.note)
        self._spawn(lambda: self._send(choice, order))

    def _spawn(self, start: Callable[[], Coroutine[None, None, None]]) -> None:
        """Run ``start()`` as a task of the service's task group (the coroutine is made in the task)."""
        if self._tasks is None:
            raise ApiError("the dispatcher is not running")
        self._sending += 1
        self._idle.clear()
        self._tasks.create_task(self._counted(start))

    async def _counted(self, start: Callable[[], Coroutine[None, None, None]]) -> None:
        try:
            await start()
        except StoreError as exc:  # the mail stays as stored: its deadline brings it back
            log.error("dispatch: %s", exc)
        finally:
            self._sending -= 1
            self._poke()

    async def _send(self, choice: Assignment, order: MailOrder) -> None:
        try:
            async with asyncio.timeout(self.settings.assign_timeout_s):
                await self.gateway.assign(choice.drone, order)
        except (AssignRefused, TimeoutError) as exc:
            reason = exc.reason if isinstance(exc, AssignRefused) else "no answer in time"
            log.info("drone %s did not take mail %s: %s", choice.drone, choice.mail_id, reason)
            self._exclude(choice.mail_id, choice.drone, self.clock() + self.settings.refuse_backoff_s)
            await self._decide([Requeue(choice.mail_id, choice.drone, f"drone {choice.drone} did not take it: "
                                                                      f"{reason}")])

    def _exclude(self, mail_id: str, drone: str, until: float) -> None:
        self._excluded.setdefault(mail_id, {})[drone] = until

    def _current_exclusions(self) -> dict[str, set[str]]:
        now = self.clock()
        current = {}
        for mail_id, drones in list(self._excluded.items()):
            for drone, until in list(drones.items()):
                if until <= now:
                    del drones[drone]
            if drones:
                current[mail_id] = set(drones)
            else:
                del self._excluded[mail_id]
        return current

    # --------------------------------------------------- giving up
    async def _decide(self, decisions: list[Decision]) -> None:
        await asyncio.gather(*(self._give_up(d) for d in decisions))

    async def _give_up(self, decision: Decision) -> None:
        status = Status.QUEUED if isinstance(decision, Requeue) else Status.FAILED
        try:
            await self.store.transition(decision.mail_id, status, reason=decision.reason,
                                        only_from=IN_FLIGHT)
        except (IllegalTransition, MailNotFound) as exc:
            log.info("not giving up: %s", exc)
            self._resync(decision.mail_id)
            return
        log.info("mail %s %s: %s", decision.mail_id, status.value, decision.reason)
        self._exclude(decision.mail_id, decision.drone, self.clock() + self.settings.refuse_backoff_s)
        if decision.drone in self.gateway.drones():
            self.cancel_later(decision.drone, decision.mail_id)

    def _resync(self, mail_id: str) -> None:
        """After a transition was refused: hold the mail in flight only if the store says so."""
        record = self.store.get(mail_id)
        if record is None or record.status not in IN_FLIGHT or record.drone is None:
            self.in_flight.pop(mail_id, None)
        else:
            deadline = self.clock() + self.settings.assign_timeout_s
            self.in_flight[mail_id] = InFlight(mail_id, record.drone, record.status, deadline)

    def cancel_later(self, drone: str, mail_id: str) -> None:
        """Tell ``drone`` to drop ``mail_id``, in the background (best effort)."""
        self._spawn(lambda: self.cancel_on(drone, mail_id))

    async def cancel_on(self, drone: str, mail_id: str) -> None:
        """Best effort: tell ``drone`` to drop ``mail_id``, waiting at most the assign timeout."""
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(self.settings.assign_timeout_s):
                await self.gateway.cancel(drone, mail_id)

    async def _lost(self, drone: str) -> None:
        """A drone lost may be only cut off, flying on. Mail it was not cleared to pick up is requeued
        (it will not take it on board); mail cleared or on board waits for it, or the operator's release."""
        log.warning("drone %s lost", drone)
        self.gone.add(drone)
        self.cleared_when_lost |= {m.mail_id for m in self.in_flight.values()
                                   if m.drone == drone and m.mail_id in self.cleared}
        await self._decide(dispatch.on_drone_lost(self.in_flight.values(), drone, self.cleared))

    async def released(self, drone: str) -> None:
        """The operator saw ``drone``, gone, out of the air: what it carried is lost with it."""
        self.gone.discard(drone)
        await self._decide(dispatch.on_drone_released(self.in_flight.values(), drone, self.cleared))

    # ----------------------------------------------------------- reports
    async def _report(self, report: MailStatusReport) -> None:
        held = self.in_flight.get(report.mail_id)
        if held is None or held.drone != report.drone:
            self._ignore(report, held)
            return
        deadline = self.clock() + self.settings.assign_timeout_s
        self.in_flight[report.mail_id] = InFlight(held.mail_id, held.drone, held.status, deadline)
        try:
            await self._apply_report(report)
        except IllegalTransition as exc:
            log.info("report %s from %s about %s ignored: %s", report.status, report.drone, report.mail_id, exc)

    async def _apply_report(self, report: MailStatusReport) -> None:
        mail_id, drone, why = report.mail_id, report.drone, report.reason
        if report.status == "picked_up":
            await self.store.transition(mail_id, Status.PICKED_UP, reason=why)
        elif report.status == "delivered":
            await self.store.transition(mail_id, Status.DELIVERED, reason=why)
        elif report.status == "failed":
            await self.store.transition(mail_id, Status.FAILED, reason=why or f"drone {drone} failed it")
        elif report.status == "rejected":
            await self._rejected(report)
        elif report.status == "started":
            self._clear(drone, mail_id)
        # accepted: the refreshed deadline is all

    def _clear(self, drone: str, mail_id: str) -> None:
        """Held as the drone's from now, lost or not: then it may take the mail on board."""
        if mail_id not in self.cleared:
            self.cleared.add(mail_id)
            log.info("mail %s cleared for pickup by drone %s", mail_id, drone)
        self._spawn(lambda: self.gateway.clear(drone, mail_id))

    async def _rejected(self, report: MailStatusReport) -> None:
        """A rejection may be passing (a goal taken, a charger busy): the drone is offered the mail
        again after a backoff that doubles each time. Once every drone has rejected it
        ``max_rejections`` times, no drone is likely to fly it: it fails."""
        times = self._rejections.setdefault(report.mail_id, {})
        times[report.drone] = times.get(report.drone, 0) + 1
        backoff = self.settings.refuse_backoff_s * 2 ** (times[report.drone] - 1)
        self._exclude(report.mail_id, report.drone, self.clock() + backoff)
        why = f"drone {report.drone} rejected it: {report.reason or 'no reason given'}"
        limit = self.settings.max_rejections
        if all(times.get(drone, 0) >= limit for drone in {*self.gateway.drones(), report.drone}):
            await self.store.transition(report.mail_id, Status.FAILED,
                                        reason=f"every drone rejected it {limit} time(s); {why}")
        else:
            await self.store.transition(report.mail_id, Status.QUEUED, reason=why)

    def _ignore(self, report: MailStatusReport, held: InFlight | None) -> None:
        what = f"report {report.status!r} from drone {report.drone!r} about mail {report.mail_id!r} ignored"
        if report.drone not in self.gateway.drones() and (held is None or held.drone != report.drone):
            log.warning("%s: unknown drone", what)
        elif held is not None:
            log.warning("%s: drone %s holds that mail", what, held.drone)
        elif (record := self.store.get(report.mail_id)) is None:
            log.warning("%s: unknown mail", what)
        else:
            log.info("%s: the mail is %s", what, record.status.value)
