"""``/v1/fleet`` and ``/v1/workspace``: what the drones are doing, and where they fly."""

from __future__ import annotations

from fastapi import APIRouter

from api.deps import AUTH_RESPONSES, CallerDep, OperatorDep
from api.models import ErrorOut, FleetPublic, WorkspacePublic

router = APIRouter(prefix="/v1", tags=["fleet"], responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}})


@router.get("/fleet", response_model=FleetPublic)
async def fleet(caller: OperatorDep) -> FleetPublic:
    """The latest state of every live drone, and the last known state of each that left (operators only)."""
    known = caller.service.watch.known()
    return FleetPublic(drones=[d for d in known if d.alive], lost=[d for d in known if not d.alive])


@router.get("/workspace", response_model=WorkspacePublic)
async def workspace(caller: CallerDep) -> WorkspacePublic:
    """The grid the fleet flies in: size, obstacles as cells, chargers, timing, and where it is on Earth."""
    return caller.service.workspace_public
