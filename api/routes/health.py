"""``/healthz`` (the process answers) and ``/readyz`` (the store and the dispatcher run, and the service
is linked to the fleet: unlinked, a mail it took could reach no drone); no token needed."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response, status

from api.deps import Service
from api.models import HealthOut, ReadyOut

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut)
async def healthz() -> HealthOut:
    return HealthOut(status="ok")


@router.get("/readyz", response_model=ReadyOut, responses={503: {"model": ReadyOut, "description": "not ready"}})
async def readyz(request: Request, response: Response) -> ReadyOut:
    service: Service | None = getattr(request.app.state, "service", None)
    if service is None or not service.ready:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
        return ReadyOut(ready=False, fleet_connected=False, drones=0, queued=0, held_by_drones=0)
    connected = service.gateway.is_open()
    if not connected:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    return ReadyOut(ready=connected, fleet_connected=connected, drones=len(service.gateway.drones()),
                    queued=service.dispatcher.queued, held_by_drones=len(service.dispatcher.in_flight))
