"""Shared pieces of the service tests: a workspace, tokens, the service in-process, the service as a process.

* :func:`running` runs the app's lifespan in the test's event loop, with an httpx client on
  it (ASGI, no socket) and a :class:`SimulatedGateway` the test steps by hand by default.
* :class:`ServiceProcess` runs ``drona serve`` (simulated gateway) on a free port, for the
  tests that need a real socket, a real crash or a browser.
* :func:`browser` is headless Chromium, for the tests of what a page shows.

Async tests are plain functions calling :func:`run` (asyncio.run with a time limit).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import AsyncIterator, Callable, Coroutine, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest
from fastapi import FastAPI

from api.deps import Service
from api.main import create_app
from api.settings import ApiSettings
from api.store import MailRecord
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import workspace_from_mapping
from tests.api.simulated import SimulatedGateway

REPO = Path(__file__).resolve().parents[2]
OPERATOR = "operator-token-0123456789"
SUBMITTER = "submitter-token-0123456789"
OTHER_SUBMITTER = "submitter-two-0123456789"
TOKENS = f"operator:{OPERATOR}:ops submitter:{SUBMITTER}:alice submitter:{OTHER_SUBMITTER}:bob"

#: 10 x 8 x 1: a wall in the middle, two chargers, three drones, a walled-off pocket at [9, 4, 0].
WORKSPACE: dict[str, Any] = {
    "name": "test",
    "size": [10, 8, 1],
    "obstacles": [{"box": [[4, 2, 0], [5, 5, 0]]}, [9, 3, 0], [8, 4, 0], [9, 5, 0]],
    "charging_stations": [[0, 0, 0], [9, 7, 0]],
    "drones": {"d1": [1, 0, 0], "d2": [2, 0, 0], "d3": [8, 7, 0]},
    "parking": [[0, 7, 0], [9, 0, 0]],
}
T = TypeVar("T")


def run(coro: Coroutine[Any, Any, T], timeout: float = 30.0) -> T:
    async def bounded() -> T:
        async with asyncio.timeout(timeout):
            return await coro

    return asyncio.run(bounded())


@pytest.fixture
def workspace() -> Workspace:
    return workspace_from_mapping(WORKSPACE, source="test.yaml")


def api_settings(**values: Any) -> ApiSettings:
    """``ApiSettings(**values)``, which mypy without pydantic's plugin takes as needing every field."""
    return ApiSettings.model_validate(values)


@pytest.fixture
def settings(tmp_path: Path) -> ApiSettings:
    return api_settings(db=tmp_path / "mail.db", tokens=TOKENS, assign_timeout_s=5.0, refuse_backoff_s=0.5)


def auth(token: str = OPERATOR) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@dataclass
class Harness:
    app: FastAPI
    client: httpx.AsyncClient
    gateway: SimulatedGateway

    @property
    def service(self) -> Service:
        service: Service = self.app.state.service
        return service

    async def submit(self, pickup: list[int], dropoff: list[int], priority: int = 5, token: str = OPERATOR,
                     **extra: Any) -> dict[str, Any]:
        res = await self.client.post("/v1/mail", json={"pickup": pickup, "dropoff": dropoff, "priority": priority,
                                                       **extra}, headers=auth(token))
        assert res.status_code == 201, res.text
        body: dict[str, Any] = res.json()
        return body

    async def until(self, predicate: Callable[[], bool], timeout: float = 5.0) -> None:
        """Wait until ``predicate()`` holds, re-checking at each event of the service's bus."""
        with self.service.bus.subscribe() as sub:
            async with asyncio.timeout(timeout):
                while not predicate():
                    await sub.queue.get()

    def drone_of(self, mail_id: str) -> str | None:
        record = self.service.store.get(mail_id)
        return record.drone if record is not None else None

    def record(self, mail_id: str) -> MailRecord:
        record = self.service.store.get(mail_id)
        assert record is not None
        return record

    def status(self, mail_id: str) -> str:
        record = self.service.store.get(mail_id)
        assert record is not None
        return record.status.value

    async def steps(self, count: int) -> None:
        """Move the simulated drones ``count`` steps, letting the service take each step in."""
        for _ in range(count):
            self.gateway.tick()
            await asyncio.sleep(0)  # one loop turn: the dispatcher takes the step's events
            await self.service.dispatcher.idle()


@contextlib.asynccontextmanager
async def running(settings: ApiSettings, workspace: Workspace,
                  gateway: SimulatedGateway | None = None) -> AsyncIterator[Harness]:
    gateway = gateway or SimulatedGateway(workspace, step_s=None)
    app = create_app(settings, gateway, workspace)
    async with app.router.lifespan_context(app):
        await asyncio.wait_for(gateway.opened.wait(), 5)  # ready, as a client waiting on /readyz finds it
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            yield Harness(app, client, gateway)


class ServiceProcess:
    """``drona serve`` with the simulated gateway, in its own process; ``url`` once it listens."""

    def __init__(self, workspace_file: Path, db: Path, *extra: str, sim_step: float = 0.02,
                 env: dict[str, str] | None = None) -> None:
        self.args = [sys.executable, "-m", "fleet.cli", "serve", "--workspace", str(workspace_file), "--db", str(db),
                     "--port", "0", "--gateway", "simulated", "--sim-step", str(sim_step), "--log-level", "warning",
                     *extra]
        full_env = {**os.environ, "DRONA_API_TOKENS": TOKENS, "PYTHONPATH": str(REPO), **(env or {})}
        self.proc = subprocess.Popen(self.args, cwd=REPO, env=full_env, stdout=subprocess.PIPE, text=True)
        self.url = self._wait_listening(timeout=30.0)

    def _wait_listening(self, timeout: float) -> str:
        found: list[str] = []
        reader = threading.Thread(target=self._read_until_listening, args=(found,), daemon=True)
        reader.start()
        reader.join(timeout)
        if not found:
            self.kill()
            pytest.fail(f"drona serve did not announce its address in {timeout} s: {self.args}")
        return found[0]

    def _read_until_listening(self, found: list[str]) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if "listening on " in line:
                found.append(line.rsplit(" ", 1)[-1].strip())
                return

    def kill(self) -> None:
        """kill -9."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        if self.proc.stdout is not None:
            self.proc.stdout.close()

    def stop(self) -> int:
        """SIGTERM, and the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(15)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        return code


@pytest.fixture
def workspace_file(tmp_path: Path) -> Path:
    import json

    path = tmp_path / "ws.json"
    path.write_text(json.dumps(WORKSPACE))
    return path


@pytest.fixture
def service(workspace_file: Path, tmp_path: Path) -> Iterator[ServiceProcess]:
    """``drona serve`` on the test workspace, stopped by SIGTERM at the end (and it must stop cleanly)."""
    proc = ServiceProcess(workspace_file, tmp_path / "mail.db")
    yield proc
    assert proc.stop() == 0


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@pytest.fixture
def browser() -> Iterator[Any]:
    """Headless Chromium (Debian's, driven by Playwright); the test is skipped, saying why, without it."""
    if not Path(CHROMIUM).exists():
        print(f"skipping the browser test: no Chromium at {CHROMIUM} (apt-get install chromium)")
        pytest.skip(f"no Chromium at {CHROMIUM}: apt-get install chromium")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("skipping the browser test: the playwright package is not installed")
        pytest.skip("the playwright package is not installed")
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            yield chromium
        finally:
            chromium.close()
