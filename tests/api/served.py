"""``Served``: the service in this process, on a real socket, with a :class:`SimulatedGateway` the test drives.

A browser test needs a real socket, and needs to act on the fleet while the page watches (freeze a
drone's link, give a drone an alarm, cut the service off the fleet). uvicorn runs the app on a
thread with its own event loop; :meth:`Served.call` runs a function on that loop (the gateway's
listeners must be called there) and waits for it.
"""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Callable
from typing import Any

import uvicorn

from api.main import create_app
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.simulated import SimulatedGateway


class Served:
    def __init__(self, settings: ApiSettings, workspace: Workspace, *, port: int = 0, step_s: float = 0.1) -> None:
        self.gateway = SimulatedGateway(workspace, step_s=step_s)
        self.app = create_app(settings, self.gateway, workspace)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.port = self.sock.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(self.app, http="h11", log_level="warning", timeout_graceful_shutdown=1)
        self.server = uvicorn.Server(config)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread = threading.Thread(target=lambda: asyncio.run(self._serve()), name="served", daemon=True)
        self.thread.start()
        self._wait(lambda: self.server.started, "the service did not start")

    async def _serve(self) -> None:
        self.loop = asyncio.get_running_loop()
        await self.server.serve(sockets=[self.sock])

    def _wait(self, ready: Callable[[], bool], why: str, timeout: float = 15.0) -> None:
        done = threading.Event()
        for _ in range(int(timeout / 0.05)):
            if ready():
                return
            done.wait(0.05)
        raise TimeoutError(why)

    def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` on the service's event loop; its result."""
        async def on_loop() -> Any:
            return fn(*args)

        assert self.loop is not None
        return asyncio.run_coroutine_threadsafe(on_loop(), self.loop).result(10)

    def stop(self) -> None:
        """End the event streams (they would hold the shutdown up), then stop the server."""
        service = getattr(self.app.state, "service", None)
        if service is not None:
            self.call(service.bus.close)
        self.server.should_exit = True
        self.thread.join(15)
        self.sock.close()
        assert not self.thread.is_alive(), "the service did not stop"
