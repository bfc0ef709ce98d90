"""``create_app``: the FastAPI app, and the lifespan that runs its background work in one task group.

The task group holds the store's writer, the dispatcher (and the exchanges it
starts with drones), the gateway and the WAL checkpointer. Shutdown cancels
them all; the writer closes the database last.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from api.commands import FleetCommands
from api.deps import BEARER_SCHEME, Service
from api.dispatcher import Dispatcher
from api.errors import ConfigError, StoreError
from api.events import EventBus
from api.fastlane import FastLane
from api.gateway import FleetGateway
from api.handlers import http_error, store_unavailable, validation_error
from api.headlimit import HeadLimit
from api.models import AlarmPublic, BaseMapPublic, LogEntryPublic, MailCreate, MailPublic, WorkspacePublic
from api.routes import alarms, dashboard, docs, events, fleet, health, mail, stats
from api.routes import commands as command_routes
from api.settings import ApiSettings
from api.store import Change, Store
from api.validation import MailChecker
from api.watch import FleetWatch
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace

log = logging.getLogger(__name__)
#: Largest request body accepted (a mail request is well under 1 KiB).
MAX_BODY_BYTES = 64 * 1024
#: Largest request line and headers accepted (see api.headlimit; ``drona serve`` has uvicorn's h11 hold
#: no more than this of an incomplete head).
MAX_HEAD_BYTES = 32 * 1024


class _Shutdown(Exception):
    """Raised into the task group at shutdown, to cancel its tasks."""


def create_app(settings: ApiSettings, gateway: FleetGateway, workspace: Workspace | None = None) -> FastAPI:
    """The service for ``workspace`` (default: ``settings.workspace``), reaching the drones through ``gateway``."""
    if workspace is None:
        if settings.workspace is None:
            raise ConfigError("no workspace: set DRONA_API_WORKSPACE or pass --workspace")
        workspace = load_workspace(settings.workspace)
    ws = workspace
    tokens = settings.token_table()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store(settings.db, synchronous=settings.synchronous, max_batch=settings.max_batch)
        bus = EventBus(settings.sse_queue)
        checker = MailChecker(ws)
        dispatcher = Dispatcher(store, gateway, checker.distance, bus, settings)
        watch = FleetWatch(dispatcher, store, bus)  # between the gateway and the dispatcher: it passes all on
        store.listeners += [dispatcher.on_commit, watch.on_commit, _publisher(bus)]
        _publish_watch(watch, bus)
        gateway.listen(watch)
        dispatcher.resume()
        commands = FleetCommands(store, dispatcher, gateway, bus)
        commands.restore()
        service = Service(settings, ws, WorkspacePublic.of(ws, _base_map(settings)), tokens, checker, store, bus,
                          gateway, dispatcher, commands, watch=watch)
        app.state.service = service
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(store.run(), name="store-writer")
                tasks.create_task(dispatcher.run(tasks), name="dispatcher")
                tasks.create_task(gateway.run(), name="gateway")
                tasks.create_task(_checkpointer(store, settings.checkpoint_s), name="checkpointer")
                tasks.create_task(watch.alarms.run(), name="alarms")
                service.ready = True
                log.info("serving %s with %s", settings.db, type(gateway).__name__)
                yield
                service.ready = False
                raise _Shutdown
        except* _Shutdown:
            pass

    # FastAPI's own /docs and /redoc load their scripts from a CDN: ours (api.routes.docs) are served here.
    app = FastAPI(title="drona-gcs", version="1", lifespan=lifespan, max_body_size=MAX_BODY_BYTES,
                  docs_url=None, redoc_url=None,
                  description="Mail requests for a DRONA drone fleet: submit, follow, cancel; the fleet's live state.")
    for module in (mail, fleet, command_routes, alarms, stats, events, health, dashboard, docs):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=dashboard.STATIC_DIR), name="static")
    app.mount(docs.ASSETS_URL, StaticFiles(directory=docs.ASSETS_DIR), name="docs-assets")
    app.add_middleware(FastLane, method="POST", path="/v1/mail", endpoint=mail.submit)
    app.add_middleware(HeadLimit, limit=MAX_HEAD_BYTES)  # added last: it runs first
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StoreError, store_unavailable)
    return app


def _openapi(app: FastAPI) -> dict[str, Any]:
    """FastAPI's document, with the bearer scheme on every /v1 operation (auth is one plain dependency)."""
    if app.openapi_schema is None:
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        components = schema.setdefault("components", {})
        components.setdefault("securitySchemes", {})["bearer"] = BEARER_SCHEME
        components.setdefault("schemas", {})["MailCreate"] = MailCreate.model_json_schema(
            ref_template="#/components/schemas/{model}")
        for path, operations in schema["paths"].items():
            if path.startswith("/v1/"):
                for operation in operations.values():
                    operation["security"] = [{"bearer": []}]
        app.openapi_schema = schema
    return app.openapi_schema


def _publish_watch(watch: FleetWatch, bus: EventBus) -> None:
    """The watch's log entries and alarm changes as server-sent events ``log`` and ``alarm``."""
    watch.on_entry = lambda e: bus.publish("log", lambda: LogEntryPublic.of(e).model_dump_json())
    watch.on_alarm = lambda a: bus.publish("alarm", lambda: AlarmPublic.of(a).model_dump_json())


def _base_map(settings: ApiSettings) -> BaseMapPublic | None:
    return BaseMapPublic(url=settings.tile_url, attribution=settings.tile_attribution) if settings.tile_url else None


def _publisher(bus: EventBus) -> Callable[[Change], None]:
    def publish(change: Change) -> None:
        bus.publish("mail", lambda: MailPublic.of(change.record).model_dump_json())

    return publish


async def _checkpointer(store: Store, every_s: float) -> None:
    """A checkpoint at start (a WAL left by a crash), then every ``every_s``: a timer, not a wait for an event."""
    while True:
        try:
            busy, frames, done = await store.checkpoint()
        except StoreError as exc:  # tried again at the next period
            log.warning("WAL checkpoint failed: %s", exc)
        else:
            if busy:
                log.info("WAL checkpoint left %d of %d frames (readers busy)", frames - done, frames)
        await asyncio.sleep(every_s)
