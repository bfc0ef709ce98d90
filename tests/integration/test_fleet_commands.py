"""The operator's fleet commands through `drona serve`'s API, over real agents and fake vehicles: pause
and resume, recall one drone, land one drone where it is. Judged from the service's records (mail
history, the commands' audit trail) and the flight record, which must audit clean."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.integration.harness import LEAD_STEPS, FleetProcesses
from tests.integration.runs import check_run_record
from tests.integration.test_service_fleet import HEADERS, Events, start_service

pytestmark = pytest.mark.slow


def _post(url: str, path: str, body: dict[str, Any] | None = None) -> httpx.Response:
    return httpx.post(f"{url}{path}", headers=HEADERS, json=body, timeout=30)


def _mail(url: str, pickup: list[int], dropoff: list[int], priority: int = 5) -> str:
    res = _post(url, "/v1/mail", {"pickup": pickup, "dropoff": dropoff, "priority": priority})
    assert res.status_code == 201, res.text
    mail_id: str = res.json()["id"]
    return mail_id


def _until(check: Callable[[], bool], timeout: float, what: str, fleet: FleetProcesses) -> None:
    """Poll the service until ``check()`` (each call a GET or two): bounded."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}\n{fleet.logs()}")
        time.sleep(0.1)


def _status(url: str, mail_id: str) -> dict[str, Any]:
    body: dict[str, Any] = httpx.get(f"{url}/v1/mail/{mail_id}", headers=HEADERS, timeout=10).json()
    return body


def _drones(url: str) -> dict[str, dict[str, Any]]:
    return {d["id"]: d for d in httpx.get(f"{url}/v1/fleet", headers=HEADERS, timeout=10).json()["drones"]}


def _history(url: str, mail_id: str) -> list[tuple[str, str | None]]:
    body = httpx.get(f"{url}/v1/mail/{mail_id}", headers=HEADERS, timeout=10).json()
    return [(h["status"], h["drone"]) for h in body["history"]]


def test_pause_resume_recall_and_land_through_the_api(tmp_path: Path) -> None:
    fleet = FleetProcesses(tmp_path, ["d1", "d2", "d3"], agent_options=("--no-adopt-mail",))
    fleet.start()
    try:
        url = start_service(fleet, tmp_path / "mail.db")
        events = Events(url)
        events.until(lambda: set(events.drones) == set(fleet.drones), 60, "every drone", fleet.logs)

        # Pause: every drone answers; mail waits, never offered, until resumed; then it is delivered.
        paused = _post(url, "/v1/fleet/pause")
        assert paused.status_code == 200 and {a["drone"] for a in paused.json()["acks"]} == set(fleet.drones)
        first = _mail(url, [2, 2, 0], [7, 7, 0])
        then = max(d["step"] for d in events.drones.values())
        events.until(lambda: min(d["step"] for d in events.drones.values()) >= then + 4, 30, "a few steps",
                     fleet.logs)
        assert _history(url, first) == [("queued", None)]
        assert _post(url, "/v1/fleet/resume").status_code == 200
        _until(lambda: _status(url, first)["status"] == "delivered", 120, "the first mail delivered", fleet)

        # Recall the drone that took a mail: the mail goes back and another drone delivers it.
        # The pickup is far from where the drones park: recalled on its way there.
        second = _mail(url, [8, 8, 0], [2, 8, 0])
        _until(lambda: _status(url, second)["status"] == "assigned", 30, "the second mail assigned", fleet)
        recalled = _status(url, second)["drone"]
        res = _post(url, f"/v1/fleet/drones/{recalled}/recall")
        assert res.status_code == 200, res.text
        _until(lambda: _status(url, second)["status"] == "delivered", 150, "the second mail delivered", fleet)
        steps = _history(url, second)
        assert ("assigned", recalled) in steps and steps[-1][0] == "delivered" and steps[-1][1] != recalled, steps
        assert _post(url, f"/v1/fleet/drones/{recalled}/resume").status_code == 200

        # Land a drone mid-flight: it stops at the cell its plan reached once a round could end, and stays.
        third = _mail(url, [8, 8, 0], [8, 1, 0])

        def flying_to_the_pickup() -> bool:
            mail = _status(url, third)
            drone = _drones(url).get(mail["drone"] or "", {})
            return mail["status"] == "assigned" and bool((drone.get("trajectory") or {}).get("cells"))

        _until(flying_to_the_pickup, 60, "the third mail's drone flying", fleet)
        lander = _status(url, third)["drone"]
        at_step = _drones(url)[lander]["step"]
        assert _post(url, f"/v1/fleet/drones/{lander}/land").status_code == 200
        _until(lambda: _status(url, third)["status"] == "delivered", 150, "the third mail delivered", fleet)
        commands = httpx.get(f"{url}/v1/fleet/commands", headers=HEADERS, timeout=10).json()
        assert [(c["action"], c["drone"], c["by"]) for c in commands] == [
            ("land", lander, "demo"), ("resume", recalled, "demo"), ("recall", recalled, "demo"),
            ("resume", None, "demo"), ("pause", None, "demo")]
        result = check_run_record(fleet)
        flown = result.trajectories[lander]
        settled = at_step + LEAD_STEPS + 4  # the round, and the vehicle's last cell
        stays = {flown.at(k) for k in range(settled, flown.end_step + 1)}
        assert len(stays) == 1, f"{lander} moved after it was landed at step {at_step}: {sorted(stays)}"
        [stop], there = stays, flown.at(at_step)
        assert stop != (8, 8, 0), f"{lander} flew on to the pickup"  # it was far from it when landed
        assert sum(abs(a - b) for a, b in zip(stop, there, strict=True)) <= LEAD_STEPS + 2, (stop, there)
        assert _history(url, third)[-1][1] != lander
    finally:
        fleet.kill_all()
