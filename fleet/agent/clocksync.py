"""Clock offsets between drones, and the check of the paper's bound beta.

The safety argument (Delta = ceil(beta / tau)) assumes every two drones'
clocks differ by at most beta. We check it: each agent asks its peers for
their clock (a Zenoh query) and, NTP-style, takes the offset as the peer's
time minus the midpoint of the round trip; the estimate is off by at most
half the round trip. The bound is broken only when the skew is *provably*
above beta: ``|offset| - rtt/2 > beta``. (A point estimate would raise false
alarms on any fleet with beta 0, and loopback round trips are ~0.1 ms.)
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType


@dataclass(frozen=True)
class OffsetSample:
    offset_s: float  #: peer clock minus mine
    error_s: float  #: half the round trip: the estimate's bound

    @classmethod
    def measure(cls, sent: float, peer_time: float, received: float) -> OffsetSample:
        return cls(peer_time - (sent + received) / 2, max(0.0, received - sent) / 2)

    def exceeds(self, beta_s: float) -> bool:
        return abs(self.offset_s) - self.error_s > beta_s


@dataclass
class ClockCheck:
    """Each peer judged on its tightest recent sample (the smallest round trip of the last
    ``keep``): one slow answer, from a peer busy planning, must neither hide a skew nor clear
    an alarm."""

    beta_s: float
    keep: int = 4
    samples: dict[str, deque[OffsetSample]] = field(default_factory=dict)
    #: each peer's tightest sample: the state a drone publishes at every step names them all
    _best: Mapping[str, OffsetSample] | None = field(default=None, init=False, repr=False, compare=False)
    _offsets: dict[str, float] | None = field(default=None, init=False, repr=False, compare=False)

    def observe(self, peer: str, sample: OffsetSample) -> None:
        self.samples.setdefault(peer, deque(maxlen=self.keep)).append(sample)
        self._best = self._offsets = None

    def forget(self, peer: str) -> None:
        self.samples.pop(peer, None)
        self._best = self._offsets = None

    @property
    def peers(self) -> Mapping[str, OffsetSample]:
        if self._best is None:
            best = {p: min(s, key=lambda x: x.error_s) for p, s in self.samples.items() if s}
            self._best = MappingProxyType(best)  # read-only: it is handed to every caller until the next sample
        return self._best

    def offsets_s(self) -> dict[str, float]:
        """Each peer's offset to the microsecond, by name, as the state says it: the same dict until
        the next sample (not to be changed)."""
        if self._offsets is None:
            self._offsets = {p: round(s.offset_s, 6) for p, s in sorted(self.peers.items())}
        return self._offsets

    def violations(self) -> dict[str, OffsetSample]:
        """The peers whose clock is provably more than beta from mine."""
        return {p: s for p, s in self.peers.items() if s.exceeds(self.beta_s)}

    def mine_is_off(self, fleet: int = 0) -> bool:
        """Whether my clock is the one off: beyond beta from most of the ``fleet``'s other drones (or of
        those measured, if more), not just from the first to answer (from the only one, with two drones:
        either may be, so both hold)."""
        return 2 * len(self.violations()) > max(len(self.peers), fleet)

    def alarm(self, fleet: int = 0) -> str | None:
        bad = self.violations()
        if not bad:
            return None
        worst = max(bad.items(), key=lambda item: abs(item[1].offset_s))
        skew = (f"clock skew: {worst[0]}'s clock is {worst[1].offset_s * 1000:+.1f} ms "
                f"(+/- {worst[1].error_s * 1000:.1f}) from mine, beyond beta {self.beta_s * 1000:.0f} ms")
        if self.mine_is_off(fleet):
            return (f"{skew}, and {len(bad)} of {len(self.peers)} peers' are: mine is off, so I hold where my "
                    "plan ends and take no task until it is back within")
        return f"{skew}: {', '.join(sorted(bad))} out of the fleet's bound, held as an obstacle where it flies"
