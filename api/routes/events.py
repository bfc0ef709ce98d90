"""``/v1/events``: server-sent events of mail status changes and drone states.

Events: ``mail`` (a mail as in ``GET /v1/mail/{id}`` without history), ``drone``
(a drone as in ``GET /v1/fleet``), ``drone_lost`` (``{"id": ...}``), ``alarm`` (an
alarm as in ``GET /v1/alarms``, when raised, cleared or acknowledged), ``log`` (an
entry as in ``GET /v1/log``), ``command`` (an operator's command as in
``GET /v1/fleet/commands``). The stream starts with a ``drone`` event for every drone known:
live, or (``alive`` false) the last state of one that left. EventSource cannot set headers, so
this route (and only this one) also takes the token as ``?access_token=``.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

from fastapi import APIRouter
from fastapi.responses import StreamingResponse
from pydantic import TypeAdapter

from api.deps import AUTH_RESPONSES, Service, StreamOperatorDep
from api.events import ServerEvent
from api.gateway import DroneView
from api.models import ErrorOut

router = APIRouter(prefix="/v1", tags=["events"])
_DRONE_JSON = TypeAdapter(DroneView)


@router.get("/events", response_class=StreamingResponse, responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut},
    200: {"content": {"text/event-stream": {}}, "description": "a stream of server-sent events"}})
async def events(caller: StreamOperatorDep) -> StreamingResponse:
    """Mail status changes and drone states, as they happen (operators only)."""
    return StreamingResponse(_stream(caller.service), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


async def _stream(service: Service) -> AsyncIterator[bytes]:
    with service.bus.subscribe() as sub:
        yield b": connected\n\n"
        for view in service.watch.known():  # those that left too, alive false: shown where last seen
            yield ServerEvent("drone", _DRONE_JSON.dump_json(view).decode()).encode()
        while True:
            try:
                async with asyncio.timeout(service.settings.sse_ping_s):
                    event = await sub.queue.get()
            except TimeoutError:
                yield b": ping\n\n"
                continue
            if event is None:  # fell too far behind
                return
            yield event.encode()
