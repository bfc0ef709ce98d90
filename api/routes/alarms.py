"""``/v1/alarms`` and ``/v1/log``: the fleet's alarms, which operators acknowledge, and the event log.

An acknowledgement is stored with who made it and when (the audit trail); see :mod:`api.alarms`
for when an alarm opens and clears, and :mod:`api.watch` for what the log holds.
"""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Query, status

from api.alarms import AlarmNotFound, recent
from api.deps import AUTH_RESPONSES, OperatorDep
from api.models import AlarmPage, AlarmPublic, ErrorOut, LogEntryPublic, LogPage

router = APIRouter(prefix="/v1", tags=["alarms"], responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}})


@router.get("/alarms", response_model=AlarmPage)
async def alarms(caller: OperatorDep, active: Annotated[bool, Query(description="only those not cleared")] = False,
                 limit: Annotated[int, Query(ge=1, le=500)] = 100) -> AlarmPage:
    """The fleet's alarms, newest first (operators only)."""
    return AlarmPage(items=[AlarmPublic.of(a) for a in caller.service.store.read(lambda c: recent(c, limit, active))])


@router.post("/alarms/{n}/ack", response_model=AlarmPublic, responses={
    404: {"model": ErrorOut, "description": "no such alarm"}})
async def acknowledge(caller: OperatorDep, n: Annotated[int, Path(ge=1, le=2**62)]) -> AlarmPublic:
    """Acknowledge an alarm: stored with who and when. The first acknowledgement stands."""
    watch = caller.service.watch
    try:
        alarm = await watch.alarms.acknowledge(n, caller.principal.name, time.time())
    except AlarmNotFound as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from exc
    return AlarmPublic.of(alarm)


@router.get("/log", response_model=LogPage)
async def event_log(caller: OperatorDep, limit: Annotated[int, Query(ge=1, le=500)] = 200) -> LogPage:
    """The event log since the service started, newest first: mail lifecycle, drones joining and
    leaving, alarms raised, cleared and acknowledged (operators only)."""
    return LogPage(items=[LogEntryPublic.of(e) for e in caller.service.watch.recent(limit)])
