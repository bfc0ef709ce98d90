"""``/v1/fleet/...`` commands: pause and resume the fleet, recall, land or resume one drone, release one
that is gone (operators).

Each is recorded with who asked and the drones' answers (``GET /v1/fleet/commands``); see
:mod:`api.commands` for what the service and the drones do.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, status

from api.commands import Action, CommandRecord
from api.deps import AUTH_RESPONSES, Caller, OperatorDep
from api.models import ErrorOut

router = APIRouter(prefix="/v1/fleet", tags=["fleet"], responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}})
DroneId = Annotated[str, Path(pattern=r"^[A-Za-z0-9_.-]+$", max_length=64)]
_DRONE_RESPONSES: dict[int | str, dict[str, Any]] = {
    404: {"model": ErrorOut, "description": "no such drone in the workspace"},
    504: {"model": ErrorOut, "description": "the drone did not answer (the command is recorded)"}}


@router.post("/pause", response_model=CommandRecord)
async def pause(caller: OperatorDep) -> CommandRecord:
    """No new mail for any drone: plans under way finish, mail on board is delivered, drones park."""
    return await _run(caller, Action.PAUSE, None)


@router.post("/resume", response_model=CommandRecord)
async def resume(caller: OperatorDep) -> CommandRecord:
    """Undo every pause, recall and landing: the fleet takes mail again."""
    return await _run(caller, Action.RESUME, None)


@router.post("/drones/{drone}/recall", response_model=CommandRecord, responses=_DRONE_RESPONSES)
async def recall(caller: OperatorDep, drone: DroneId) -> CommandRecord:
    """The drone finishes its current leg, hands back its mail not on board (delivering what it carries)
    and parks; the service gives it no mail until it is resumed."""
    return await _run(caller, Action.RECALL, drone)


@router.post("/drones/{drone}/land", response_model=CommandRecord, responses=_DRONE_RESPONSES)
async def land(caller: OperatorDep, drone: DroneId) -> CommandRecord:
    """The drone stops where it is, once its peers know it stays there (a round of the protocol), and
    lands; its mail not on board is handed back. It stays until resumed."""
    return await _run(caller, Action.LAND, drone)


@router.post("/drones/{drone}/resume", response_model=CommandRecord, responses=_DRONE_RESPONSES)
async def resume_drone(caller: OperatorDep, drone: DroneId) -> CommandRecord:
    return await _run(caller, Action.RESUME, drone)


@router.post("/drones/{drone}/release", response_model=CommandRecord, responses={
    404: {"model": ErrorOut, "description": "no such drone in the workspace"},
    409: {"model": ErrorOut, "description": "the drone is in the fleet: there is nothing to release"}})
async def release(caller: OperatorDep, drone: DroneId) -> CommandRecord:
    """The operator has seen the vehicle of this drone, gone from the fleet, out of the air for good
    (landed, or taken away): every live drone stops holding the cells it may have stopped on. Recorded
    in the audit trail; the drone is held nowhere until it joins again and says where it is."""
    if drone in caller.service.gateway.drones():
        raise HTTPException(status.HTTP_409_CONFLICT, f"drone {drone} is in the fleet: there is nothing to release")
    return await _run(caller, Action.RELEASE, drone)


@router.get("/commands", response_model=list[CommandRecord])
async def commands(caller: OperatorDep,
                   limit: Annotated[int, Query(ge=1, le=500)] = 100) -> list[CommandRecord]:
    """The commands given, newest first, with who asked and what the drones answered."""
    return caller.service.commands.history(limit)


async def _run(caller: Caller, action: Action, drone: str | None) -> CommandRecord:
    service = caller.service
    if drone is not None and drone not in service.workspace.drones:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no drone {drone!r} in the workspace")
    record = await service.commands.run(action, drone, caller.principal.name)
    if action is not Action.RELEASE and drone is not None and not any(a.drone == drone and a.accepted
                                                                       for a in record.acks):
        raise HTTPException(status.HTTP_504_GATEWAY_TIMEOUT,
                            f"drone {drone} did not answer {action.value!r} (recorded as command {record.n}; "
                            f"the service hands it no mail until resumed)" if action is not Action.RESUME
                            else f"drone {drone} did not answer 'resume' (recorded as command {record.n})")
    return record
