"""What happens to a mail planner: mail assigned, cleared and handed back, legs that end (flown, not
flown, failed), the battery, and the operator's commands (see :mod:`drona_gcs.stack.mail`)."""

from __future__ import annotations

from drona_gcs.errors import ProtocolViolation
from drona_gcs.stack.mail_reach import MailPlannerBase
from drona_gcs.stack.mail_requests import (
    MAX_FAILURES,
    MAX_MISSES,
    MAX_STRIKES,
    NOT_CLEARED,
    MailAction,
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailRejected,
    MailRequest,
)
from drona_gcs.stack.mail_table import MailEvent, Phase
from drona_gcs.workspace import Cell


class MailPlannerInputs(MailPlannerBase):
    """The mail planner's inputs besides :meth:`MailPlanner.decide`."""

    def assign(self, request: MailRequest) -> None:
        if self.holds(request.id):
            return  # a duplicate assignment is harmless
        self.queue.append(request)

    def holds(self, mail_id: str) -> bool:
        """Whether ``mail_id`` is queued here, under way or on board."""
        return any(r.id == mail_id for r in self.queue) or (self.current is not None and self.current.id == mail_id)

    def clear(self, mail_id: str) -> bool:
        """The dispatcher holds ``mail_id`` as this drone's from now on: it may take it on board. False if
        no dispatcher clears this drone's mail, or if the mail is not held here: a clearance that comes
        after the mail was handed back would let it be taken on board when given again, uncleared."""
        if self.cleared is None or not self.holds(mail_id):
            return False
        self.cleared = self.cleared | {mail_id}
        return True

    def reported(self, action: MailAction) -> None:
        """A clearance is for one holding: it ends once the mail is handed back, delivered or lost."""
        if self.cleared is not None and isinstance(action, (MailRejected, MailDelivered, MailLost)):
            self.cleared = self.cleared - {action.request.id}

    def cancel(self, mail_id: str) -> bool:
        """Drop a mail still waiting in the queue; one already under way is flown to the end."""
        kept = [r for r in self.queue if r.id != mail_id]
        dropped = len(kept) != len(self.queue)
        self.queue = kept
        return dropped

    def abandon(self, reason: str) -> list[MailAction]:
        """The vehicle came down by itself (a failsafe, a pilot) and flies no more legs: every mail
        is handed back, most urgent first. One waiting, or not picked up yet, is rejected (another
        drone may fly it); one on board is lost (it is wherever the vehicle is). A leg under way
        ends with no mail: its end reports nothing."""
        handed: list[MailAction] = [MailRejected(r, reason, True) for r in sorted(self.queue, key=lambda r: r.rank)]
        self.queue = []
        if self.current is not None:
            handed.append(MailLost(self.current, reason) if self.carrying else MailRejected(self.current, reason, True))
            if self.carrying:
                self._enter(MailEvent.LOST)
            self.current = None
        return handed

    def _may_pick_up(self, request: MailRequest) -> bool:
        """Mail is taken on board only once its dispatcher knows it may be (see :attr:`cleared`): then a
        drone it loses touch with may hold it, and it gives it to no other drone meanwhile."""
        return self.cleared is None or request.id in self.cleared

    def release(self, reason: str, keep_cleared: bool = False) -> list[MailAction]:
        """Hand back every mail not on board, most urgent first (the vehicle is lost: another drone
        may fly them); mail on board stays, and with ``keep_cleared`` mail cleared for pickup (its
        dispatcher holds it as this drone's). A leg to a pickup under way ends with no mail."""
        def kept(request: MailRequest) -> bool:
            return keep_cleared and self.cleared is not None and request.id in self.cleared

        ranked = sorted(self.queue, key=lambda r: r.rank)
        handed: list[MailAction] = [MailRejected(r, reason, True) for r in ranked if not kept(r)]
        self.queue = [r for r in self.queue if kept(r)]
        if self.current is not None and not self.carrying and not kept(self.current):
            handed.append(MailRejected(self.current, reason, True))
            self.current = None
        return handed

    def make_way(self, spot: Cell, stay: int = 0, behind: frozenset[Cell] = frozenset()) -> None:
        """A peer found no plan, for a way that crosses the cell we rest on: leave for ``spot`` at
        the next decision, unless a leg is under way or the drone charges, and stay out at least
        ``stay`` steps (back home sooner, a drone walled the peer's goal in again before the peer got
        there). Mail on board goes along: a drone waiting with it for a drop-off walled off for good
        would wall others off in turn. ``behind``: chargers out of reach until we have left (the
        peer rests on their only way, and has nowhere to make way to but through our cell)."""
        if not self.busy and self.phase is not Phase.CHARGING:
            self.make_way_to, self.make_way_stay, self.make_way_behind = spot, stay, behind

    @property
    def homeless(self) -> bool:
        """Idle with no mail, no leg and nowhere to park or charge: it waits wherever it is."""
        return (not self.busy and not self.carrying and not self.queue and self.phase is Phase.IDLE
                and not self.held and self.make_way_to is None and not self._parking_spots())

    def battery_low(self) -> None:
        self._enter(MailEvent.LOW)

    def battery_recharged(self) -> None:
        self._enter(MailEvent.RECHARGED)

    def leg_done(self) -> list[MailAction]:
        """The protocol completed the current leg: we are at ``goal``."""
        if self.goal is None:
            raise ProtocolViolation(f"leg done while {self.phase.value}, with no leg under way")
        done, current, actions = self.phase, self.current, list[MailAction]()
        picked_up = done is Phase.TO_PICKUP and current is not None and self._may_pick_up(current)
        delivered = done is Phase.TO_DROPOFF and current is not None
        # First: refused, nothing else changes (a drop-off leg starts next).
        self._enter(MailEvent.PICKED_UP if picked_up else MailEvent.DELIVERED if delivered else MailEvent.ARRIVED)
        self.cell, self.goal, self.misses, self.failures, self.cut_offs = self.goal, None, 0, 0, 0
        self.cut_off_mail = frozenset()
        self.tried.clear()
        self.blocked, self.backoff = None, 0
        self.landed_here = self._parked() or self.cell in self.chargers or done is Phase.MAKING_WAY
        if current is None:
            return actions
        if picked_up:
            self.strikes.pop(current.id, None)
            actions.append(MailPickedUp(current))
        elif done is Phase.TO_PICKUP:
            actions.append(MailRejected(current, NOT_CLEARED, True))
            self.current = None
        elif delivered:
            actions.append(MailDelivered(current))
            self.current = None
        return actions

    def leg_not_flown(self, now: int) -> list[MailAction]:
        """The plan ended but telemetry never put the vehicle at the goal: the leg did not happen. It
        is tried again at once (the vehicle may only be late); a pickup missed :data:`MAX_MISSES`
        times in a row is handed back, for another drone to fly. Mail on board stays on board."""
        self._enter(MailEvent.NOT_FLOWN)
        current, carrying = self.current, self.carrying
        self.misses += 1
        self.goal, self.retry_at = None, now
        if current is None or carrying:
            return []
        self.current = None
        if self.misses < MAX_MISSES:
            self.queue.append(current)
            return []
        self.misses = 0
        return [MailRejected(current, f"its vehicle never reached the pickup {list(current.pickup)} "
                                      f"({MAX_MISSES} plans flown, none seen there)")]

    def relocate(self, cell: Cell, landed: bool) -> None:
        """The vehicle was lost and is back in ``cell``: a leg under way is over (not flown), the
        mail stays as it was (on board, or in the queue), and the next decision starts from here."""
        # Charging goes on only on the charger: elsewhere it would wait for good.
        on_charger = self.phase is Phase.CHARGING and cell in self.chargers and landed
        self._enter(MailEvent.RELOCATED_ON_CHARGER if on_charger else MailEvent.RELOCATED)
        self.cell, self.goal, self.landed_here, self.retry_at = cell, None, landed, 0
        if self.current is not None and not self.carrying:
            self.queue.append(self.current)
            self.current = None
        self.tried.clear()

    def leg_failed(self, now: int, asked: bool = True, cut_off: bool = False) -> list[MailAction]:
        """No plan was found (``asked``: by a coordination round; else the goal was known taken;
        ``cut_off``: no path at all joins start and goal): land here and try again a little later,
        from the ground (or in the air, where a peer's plan under way ends at the goal). Mail not on
        board is handed back for another drone to fly once :data:`MAX_FAILURES` rounds in a row found
        no plan to its pickup (a vehicle down may rest on it for good), or to the drop-off of the
        mail on board, or to a charger it needs (the queue behind them), and all of it once as many
        legs in a row were cut off (drones resting for good wall this one in). A leg to a cell a peer
        holds only while its plan is under way counts for none of that: the peer moves on (two mails
        with one pickup, or a peer whose clock is off passing through)."""
        passing = self.goal in self.passing
        asked = asked and not passing
        to_pickup = self.phase is Phase.TO_PICKUP and self.current is not None and not self.carrying
        to_dropoff = self.phase is Phase.TO_DROPOFF and self.carrying
        to_charger = self.phase is Phase.TO_CHARGER
        self._enter(MailEvent.FAILED)
        self.retry_at = now + self._retry_delay()
        if self.goal is not None:
            self.tried.add(self.goal)
        self.goal = None
        self.landed_here = self.landed_here or not passing  # a peer passing through: hover the short wait
        if self.current is not None and not self.carrying:
            # Not picked up yet: back in the queue, to be weighed again against priorities and battery.
            self.queue.append(self.current)
            self.current = None
        self.failures += asked and (to_pickup or to_dropoff or to_charger)
        self.cut_offs = self.cut_offs + 1 if cut_off else 0 if asked else self.cut_offs
        if to_pickup and not passing and self._struck(self.queue[-1]):
            request = self.queue.pop()
            return [MailRejected(request, f"no plan to its pickup {list(request.pickup)} in {MAX_STRIKES} legs")]
        reason = f"no plan in {MAX_FAILURES} rounds in a row"
        if cut_off and to_pickup:  # that mail only: the others may have a way
            self.cut_off_mail |= {self.queue[-1].id}
            self.cut_off_among = self.leg_among
            if self.cut_offs >= MAX_FAILURES:
                self.cut_offs = self.failures = 0
                request = self.queue.pop()
                return [MailRejected(request, f"{reason}: its pickup {list(request.pickup)} is cut off from here")]
            return []
        if self.cut_offs >= MAX_FAILURES:
            self.cut_offs = self.failures = 0
            return self.release(f"{reason}: walled in")
        if self.failures < MAX_FAILURES or not (to_pickup or to_dropoff or to_charger):
            return []
        self.failures = 0
        if to_pickup:
            request = self.queue.pop()
            return [MailRejected(request, f"{reason} to its pickup {list(request.pickup)}")]
        return self.release(f"{reason} to " + ("the drop-off of the mail on board" if to_dropoff else "a charger"))

    def _struck(self, request: MailRequest) -> bool:
        """Count a leg to ``request``'s pickup that found no plan; True at :data:`MAX_STRIKES`. Other
        legs in between (to park, to charge) do not reset the count: a vehicle down on the pickup
        would otherwise keep the mail, and the drone flying between them, for good."""
        self.strikes[request.id] = self.strikes.get(request.id, 0) + 1
        if self.strikes[request.id] < MAX_STRIKES:
            return False
        del self.strikes[request.id]
        return True

    def _retry_delay(self) -> int:
        """``retry_steps``; doubled on each failure in a row towards a cell believed taken (capped).
        Records that cell as ``blocked`` and the delay as ``backoff`` (both cleared otherwise)."""
        if not self.goal_taken or self.goal is None:
            self.blocked, self.backoff = None, 0
            return self.retry_steps
        # Counted over the goals tried in turn (two chargers, say): what grows is the wait for
        # news, and at the cap every try is a real round, which brings it.
        self.blocked = self.goal
        self.backoff = min(2 * self.backoff, self.max_retry_steps) if self.backoff else self.retry_steps
        return self.backoff


    # ------------------------------------------------------ operator's commands
    def pause(self) -> None:
        """No mail starts: legs under way are flown, mail on board is delivered."""
        self._enter(MailEvent.PAUSE)

    def hold(self) -> None:
        """Land where it is (at the next decision, or once the leg under way ends), and fly no leg at all."""
        self._enter(MailEvent.HOLD)

    def resume(self) -> None:
        """Undo :meth:`pause` and :meth:`hold`: mail starts again."""
        self._enter(MailEvent.RESUME)
