"""The service (``drona serve``) as the world models it: it gives the mail out, hears the drones'
reports on it, clears a pickup, and gives handed-back mail to another drone; and the drones' actions
carried out: messages posted, reports sent."""

from __future__ import annotations

from collections.abc import Sequence

from drona_gcs.dispatch import Candidate, choose_drone
from drona_gcs.stack.drone import DroneStack
from drona_gcs.stack.mail import MailDelivered, MailLost, MailProgress, MailRejected, MailRequest, MailStarted
from drona_gcs.stack.protocol import Braked, Broadcast, Grounded, Holding, Present, Send, State
from drona_gcs.verify.fleet import Fleet
from drona_gcs.verify.notices import SERVICE, Announce, Clear, Holds, note
from drona_gcs.verify.verdicts import cell_text


class Service(Fleet):
    """The fleet, with the service's dispatch and the drones' actions carried out."""

    def _carry_out(self, drone: str, actions: Sequence[object]) -> None:
        for action in actions:
            if isinstance(action, Send):
                self._post(drone, action.to, action.message)
            elif isinstance(action, Broadcast):
                for peer in self.config.drones:
                    if peer != drone:
                        self._post(drone, peer, action.message)
            line = note(action)
            if line:
                self.trace.append(f"{drone}: {line}")
            self.monitors.action(drone, action)
            if isinstance(action, Present):
                self._post(drone, action.to, Announce(action.trajectory, braked=action.braked))
            if isinstance(action, (Grounded, Braked)):  # as the agent does
                for peer in self.config.drones:
                    if peer != drone:
                        self._post(drone, peer, Announce(action.trajectory, grounded=isinstance(action, Grounded),
                                                         braked=isinstance(action, Braked)))
            if isinstance(action, Holding):  # as the agent does, on plan/<me>
                for peer in self.config.drones:
                    if peer != drone:
                        self._post(drone, peer, Holds(action.cells, action.for_now, action.seq))
            if isinstance(action, MailProgress):
                self.stacks[drone].mail.reported(action)
                self._report(drone, action)

    def _report(self, drone: str, action: MailProgress) -> None:
        """A drone's report on its mail: heard by the service, kept for it while cut off, lost with a
        crashed agent."""
        if drone in self.crashed:
            return
        if drone in self.apart:
            kept = self.unheard.setdefault(drone, {})
            kept.pop(action.request.id, None)
            kept[action.request.id] = action
            return
        self._service_hears(drone, action)

    def _service_hears(self, drone: str, action: MailProgress) -> None:
        """As ``drona serve``: a report on mail it holds as another's is ignored; a start is cleared, a
        hand-back given to another drone, a delivery or a loss closes the mail."""
        mail = action.request.id
        if self.holder.get(mail) != drone:
            return
        if isinstance(action, MailStarted) and mail not in self.cleared:
            self.cleared.add(mail)
            self._post(SERVICE, drone, Clear(mail))
        elif isinstance(action, MailRejected):
            self._requeue(drone, action.request)
        elif isinstance(action, (MailDelivered, MailLost)):
            del self.holder[mail]
            self.cleared.discard(mail)

    def _requeue(self, drone: str, request: MailRequest) -> None:
        """The service gives ``request`` to another drone that flies, as promptly as a message: a liveness
        bound needs the service to be fair."""
        del self.holder[request.id]
        self.cleared.discard(request.id)
        self.redispatch.append((drone, request, max(self.steps[drone], 0) + self.config.max_delay))

    def _service_lost(self, drone: str) -> None:
        """The service sees ``drone`` go: the mail it was not cleared to pick up goes to another drone;
        the rest stays its own (it may be on board). Mail cleared to a crashed agent is never delivered
        (nobody can tell whether it is on board): (d) expects it no more."""
        for mail, holder in sorted(self.holder.items()):
            if holder != drone:
                continue
            if mail not in self.cleared:
                self.trace.append(f"service: {drone} lost before the pickup of {mail}: given to another")
                self._requeue(drone, self._request(mail))
            elif drone in self.crashed:
                self.monitors.given_up(drone, self._request(mail))

    def _service_back_new(self, drone: str) -> None:
        """A restarted agent knows none of its old mail: what the service cleared it for may be on board
        the vehicle its old agent left, and is failed (never given to a second drone)."""
        for mail, holder in sorted(self.holder.items()):
            if holder == drone:
                self.trace.append(f"service: {drone} restarted: {mail} failed (it may be on board)")
                del self.holder[mail]
                self.cleared.discard(mail)
                self.monitors.given_up(drone, self._request(mail))

    def _request(self, mail_id: str) -> MailRequest:
        return next(r for r in self.config.requests if r.id == mail_id)

    def _serving(self) -> list[str]:
        """The drones the service may give mail: vehicle flying, agent alive, in touch."""
        return [d for d in self.config.drones
                if d not in self.down and d not in self.crashed and d not in self.apart and not self._off(d)]

    def _reassign(self, request: MailRequest, handed_back_by: str, serving: list[str]) -> str:
        """The drone the service gives ``request`` to, by the fleet's one rule (as ``drona serve``'s):
        of the drones ``serving`` but the one that handed it back (if there are others), the fewest
        mails held, idle first, the nearest to the pickup."""
        others = [d for d in serving if d != handed_back_by] or serving
        candidates = [Candidate(d, self._where(d), mail_held(self.stacks[d]),
                                self.stacks[d].protocol.state is not State.WAIT_FOR_TASK) for d in others]
        chosen = choose_drone(candidates, request.pickup)
        assert chosen is not None  # serving is not empty
        return chosen

    def _inject(self) -> None:
        serving = self._serving()
        if self.redispatch and serving:
            handed_back_by, request, _ = self.redispatch.pop(0)
            drone = self._reassign(request, handed_back_by, serving)
        else:
            request, drone = self.config.requests[self.injected], self.config.assignees[self.injected]
            self.injected += 1
            if drone not in serving:  # out of service, or of touch: another, or the queue until one is back
                if not serving:
                    self.trace.append(f"env: mail {request.id} waits: no drone in service and in touch")
                    self.redispatch.append((drone, request, max(self.steps[drone], 0) + self.config.max_delay))
                    return
                drone = self._reassign(request, drone, serving)
        self.last_injection_step = min(self.steps.values())
        self.trace.append(f"env -> {drone}: mail {request.id} p{request.priority} "
                          f"{cell_text(request.pickup)}->{cell_text(request.dropoff)}")
        self.monitors.given_mail(drone, request)
        self.holder[request.id] = drone
        self._carry_out(drone, self.stacks[drone].assign(request))


def mail_held(stack: DroneStack) -> int:
    """The mail a drone holds: queued, current or on board."""
    return len(stack.mail.queue) + (stack.mail.current is not None)
