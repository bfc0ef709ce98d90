"""``drona bench coordination --fault``: one drone struck mid-run while the fleet is kept busy with mail.

The drone struck (the workspace's last) runs apart from the rest: its agent and its vehicle each in a
process of their own, on a host of their own (a network namespace) for a partition. What strikes it:

* ``kill``: its agent is killed (SIGKILL), its vehicle left hovering where it was;
* ``partition``: its host's cable is cut, and mended ``--fault-for`` seconds later;
* ``clock``: its clock is ``CLOCK_OFF_BETAS`` beta ahead from its start, past the bound the fleet plans
  for (``--fault-at`` does not apply): it is excluded, the rest fly on;
* ``clock-step``: its system clock steps ``CLOCK_STEP_BETAS`` beta ahead in flight, past the fleet's
  window (``drona agent --clock-step-on-signal``); its schedule's clock takes the step up slowly;
* ``vehicle``: its vehicle's simulator is killed (SIGKILL): the link lost in flight.

Judged by the flight records (the agents' and the simulator's), audited after the run as without a fault.
"""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from dataclasses import dataclass
from enum import StrEnum

from fleet.bench.hosts import Hosts

CLOCK_OFF_BETAS = 5.0  #: how far the struck drone's clock is off, in beta: well past the bound
CLOCK_STEP_BETAS = 15.0  #: how far its system clock steps in flight: past the window (Delta tau) too
VICTIM_HOST = "struck"  #: the struck drone's host, for a partition


class Fault(StrEnum):
    KILL = "kill"
    PARTITION = "partition"
    CLOCK = "clock"
    CLOCK_STEP = "clock-step"
    VEHICLE = "vehicle"


@dataclass(frozen=True)
class FaultPlan:
    """``kind`` strikes ``at_s`` seconds into the mail; a partition lasts ``for_s``."""

    kind: Fault
    at_s: float
    for_s: float

    def describe(self, drone: str, beta_s: float) -> str:
        what = {Fault.KILL: f"{drone}'s agent killed (SIGKILL)",
                Fault.PARTITION: f"{drone}'s host cut off from the rest for {self.for_s:g} s",
                Fault.CLOCK_STEP: f"{drone}'s system clock stepped {self.clock_offset_s(beta_s):g} s ahead "
                                  f"(beta {beta_s:g} s)",
                Fault.VEHICLE: f"{drone}'s vehicle lost in flight (its simulator killed)"}
        if self.kind is Fault.CLOCK:
            return f"{drone}'s clock {self.clock_offset_s(beta_s):g} s ahead (beta {beta_s:g} s) from its start"
        return f"{what[self.kind]}, {self.at_s:g} s into the mail"

    @property
    def over_s(self) -> float:
        """Seconds into the mail the fault is over (a partition healed)."""
        return self.at_s + (self.for_s if self.kind is Fault.PARTITION else 0.0)

    def clock_offset_s(self, beta_s: float) -> float:
        """``drona agent --clock-offset`` for the struck drone's agent (0: none)."""
        return {Fault.CLOCK: CLOCK_OFF_BETAS, Fault.CLOCK_STEP: CLOCK_STEP_BETAS}.get(self.kind, 0.0) * beta_s


@dataclass
class Victim:
    """The struck drone's processes; ``hosts`` for a partition."""

    plan: FaultPlan
    agent: subprocess.Popen[bytes]
    vehicle: subprocess.Popen[bytes]
    hosts: Hosts | None = None

    async def strike(self) -> list[str]:
        """The fault, ``plan.at_s`` from now; what was done, each line with its time."""
        if self.plan.kind is Fault.CLOCK:
            return ["the clock was off from the agent's start"]
        await asyncio.sleep(self.plan.at_s)
        done = [self._did("struck")]
        if self.plan.kind is Fault.KILL:
            self.agent.kill()
        elif self.plan.kind is Fault.VEHICLE:
            self.vehicle.kill()
        elif self.plan.kind is Fault.CLOCK_STEP:  # the agent was started with --clock-step-on-signal
            self.agent.send_signal(signal.SIGUSR1)
        elif self.plan.kind is Fault.PARTITION:
            assert self.hosts is not None, "a partition cuts a host's cable"
            self.hosts.cut(VICTIM_HOST)
            await asyncio.sleep(self.plan.for_s)
            self.hosts.heal(VICTIM_HOST)
            done.append(self._did("healed"))
        return done

    @staticmethod
    def _did(what: str) -> str:
        return f"{what} at {time.strftime('%H:%M:%S')} ({time.time():.1f})"
