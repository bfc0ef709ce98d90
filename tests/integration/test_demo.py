"""`drona demo` end to end: the service, the agents and the fake vehicles it starts fly mail, and the
dashboard in headless Chromium shows it; Ctrl-C stops everything and the recorded run is safe."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import pytest

from drona_gcs.audit import audit
from drona_gcs.workspace_files import load_workspace
from fleet.cli.demo import demo_workspace
from fleet.sim.ports import free_port_block, free_udp_base
from tests.api.test_dashboard import browser  # noqa: F401  (the fixture)

pytestmark = pytest.mark.slow
TOKEN = "demo-test-token-0123456789"


def start_demo(tmp_path: Path, drones: int) -> tuple[subprocess.Popen[str], str]:
    port = free_port_block(1, socket.SOCK_STREAM)
    command = [sys.executable, "-m", "fleet.cli", "demo", "--drones", str(drones), "--port", str(port),
               "--tau", "0.5", "--speedup", "4", "--db", str(tmp_path / "demo.db"),
               "--record", str(tmp_path / "record.jsonl"), "--token", TOKEN,
               "--vehicle-port", str(free_udp_base(drones)),
               "--zenoh-port", str(free_port_block(drones, socket.SOCK_STREAM))]
    demo = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert demo.stdout is not None
    seen = []
    for line in demo.stdout:  # ends when the demo does: bounded
        seen.append(line)
        if "dashboard http" in line:
            return demo, line.split("dashboard ", 1)[1].split()[0].rstrip("/")
    raise AssertionError("the demo never printed its dashboard URL:\n" + "".join(seen))


def test_the_demo_fleet_delivers_mail_shown_live_on_the_dashboard(tmp_path: Path, browser: Any) -> None:  # noqa: F811
    demo, url = start_demo(tmp_path, drones=4)
    try:
        headers = {"Authorization": f"Bearer {TOKEN}"}
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.goto(url + "/")
        page.fill("#token", TOKEN)
        page.click("#token-form button")
        page.wait_for_selector("#conn[data-state='live']", timeout=15_000)
        page.wait_for_function("document.querySelectorAll('#map g.drone').length === 4", timeout=30_000)
        mails = []
        for pickup, dropoff, priority in (([2, 2, 0], [13, 9, 0], 5), ([8, 10, 0], [3, 6, 0], 9)):
            answer = httpx.post(f"{url}/v1/mail", headers=headers, timeout=10,
                                json={"pickup": pickup, "dropoff": dropoff, "priority": priority})
            assert answer.status_code == 201, answer.text
            mails.append(answer.json()["id"])
        first = f"#map .marker.pickup[data-id='{mails[0]}']"
        page.wait_for_selector(f"{first}[data-status='picked_up']", timeout=90_000)
        page.wait_for_selector("#map polyline.traj", timeout=10_000)  # a drone flying its plan
        page.screenshot(path=str(tmp_path / "flying.png"))
        for mail in mails:
            page.wait_for_selector(f"#mail tbody tr[data-id='{mail}'][data-status='delivered']", timeout=120_000)
        for mail in mails:
            body = httpx.get(f"{url}/v1/mail/{mail}", headers=headers, timeout=10).json()
            assert body["status"] == "delivered"
            lifecycle = [h["status"] for h in body["history"]]
            assert lifecycle[0] == "queued" and lifecycle[-1] == "delivered"
            assert lifecycle.index("assigned") < lifecycle.index("picked_up"), lifecycle
        page.close()
    finally:
        demo.send_signal(signal.SIGINT)
        output, _ = demo.communicate(timeout=150)
    assert demo.returncode == 0, output
    records = [json.loads(line) for line in (tmp_path / "record.jsonl").read_text().splitlines()]
    result = audit(load_workspace_of_demo(tmp_path), records)
    assert set(result.trajectories) == {"d1", "d2", "d3", "d4"}
    assert result.safe, result.violations[:5]


def load_workspace_of_demo(tmp_path: Path) -> Any:
    import yaml

    path = tmp_path / "demo-workspace.yaml"
    path.write_text(yaml.safe_dump(demo_workspace(4, 0.5)))
    return load_workspace(path)
