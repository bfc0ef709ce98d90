"""Agents in separate processes, each with its own fake vehicle, over real Zenoh and MAVLink.

Fleets that deliver run on loopback, the agents a Zenoh peer mesh. The fault runs (an agent killed here;
a clock off and a vehicle lost in test_agents_faults.py; a partition in test_partition.py) put each drone,
agent and vehicle, on a host of its own (a network namespace the test makes), joined through a
`drona router` per host.

Judged independently of the agents: collisions from the cells the vehicles'
telemetry put them in (the ``--record`` files, checked under Delta by the
safety checker), deliveries and their order from the status reports, battery
from the published states.
"""

from __future__ import annotations

import asyncio
import json
import signal
from collections.abc import Callable
from pathlib import Path

import pytest

from fleet.transport.wire import MailOrder, MailStatus
from tests.integration.harness import DRONA, FleetProcesses, Observer
from tests.integration.runs import check_run, check_truth, deliver_all, random_orders, unsafe

pytestmark = pytest.mark.slow



@pytest.mark.parametrize("drones, mails, hosted", [(4, 8, False), (8, 12, False), (4, 8, True)],
                         ids=["4-8", "8-12", "4-8-one-process-shared-session"])
def test_agents_deliver_every_mail_without_collisions(tmp_path: Path, drones: int, mails: int, hosted: bool) -> None:
    fleet = FleetProcesses(tmp_path, [f"d{i + 1}" for i in range(drones)], hosted=hosted)
    orders = random_orders(mails, seed=drones, fleet=fleet)
    fleet.start()
    try:
        obs = asyncio.run(deliver_all(fleet, orders, timeout=150))
        check_run(fleet, obs, orders)
    finally:
        fleet.kill_all()


def test_an_agent_killed_mid_coordination_neither_blocks_the_others_nor_loses_its_mail(
        hosted_apart: Callable[..., FleetProcesses]) -> None:
    fleet = hosted_apart(["d1", "d2", "d3", "d4"])
    doomed = MailOrder(id="doomed", pickup=[2, 6, 0], dropoff=[7, 6, 0], priority=5)
    fleet.start()
    try:
        async def scenario() -> Observer:
            async with Observer(fleet) as obs:
                await obs.parked()  # d3 must be parked before it freezes
                fleet.signal("d3", signal.SIGSTOP)  # d3 will not answer: d2's coordination stalls on it
                await obs.give(doomed, "d2")
                await obs.until(lambda: obs.states["d2"].mode == "CoordinateAndGeneratePlan", 5, "d2 coordinating")
                fleet.signal("d2", signal.SIGKILL)  # killed while it waits for d3
                fleet.signal("d3", signal.SIGCONT)
                await obs.until(lambda: "d2" not in obs.alive, 10, "d2's liveliness to go")
                # The operator's command line, as on a real fleet: it follows the mail until delivered.
                mail = await asyncio.create_subprocess_exec(
                    *DRONA, "mail", "--pickup", "8,3,0", "--dropoff", "6,7,0", "--priority", "3", "--drone", "d4",
                    "--id", "after", "--wait", "--timeout", "120", "--fleet", fleet.fleet,
                    "--connect", fleet.endpoint("d1"), "--connect", fleet.endpoint("d4"),
                    stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
                out, err = await asyncio.wait_for(mail.communicate(), 150)
                assert mail.returncode == 0, err.decode()
                lines = [json.loads(line) for line in out.decode().splitlines()]
                assert lines[0]["status"] == "accepted" and lines[-1]["status"] == "delivered"
                await obs.until(lambda: obs.delivered(["doomed", "after"]), 120, "both mails delivered")
                return obs

        obs = asyncio.run(scenario())
        taken_over = [r for r in obs.reports if r.id == "doomed" and r.status is MailStatus.REASSIGNED]
        assert taken_over and taken_over[0].drone != "d2"
        delivered_by = {r.drone for r in obs.reports if r.id == "doomed" and r.status is MailStatus.DELIVERED}
        assert delivered_by == {taken_over[0].drone}
        codes = fleet.stop()
        assert codes["d2"] == -signal.SIGKILL
        assert all(codes[d] == 0 for d in ("d1", "d3", "d4")), f"{codes}\n{fleet.logs()}"
        result = fleet.audit()
        assert result.safe, unsafe(result, fleet)
        check_truth(fleet)
    finally:
        fleet.kill_all()

