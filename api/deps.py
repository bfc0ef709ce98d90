"""Typed dependencies of the routes: the running service and the caller."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, HTTPException, Query, Request, status

from api.auth import Principal, TokenTable
from api.commands import FleetCommands
from api.dispatcher import Dispatcher
from api.events import EventBus
from api.gateway import FleetGateway
from api.models import WorkspacePublic
from api.settings import ApiSettings
from api.store import Store
from api.validation import MailChecker
from api.watch import FleetWatch
from drona_gcs.workspace import Workspace


@dataclass
class Service:
    """Everything a request may need, built by the app's lifespan."""

    settings: ApiSettings
    workspace: Workspace
    workspace_public: WorkspacePublic
    tokens: TokenTable
    checker: MailChecker
    store: Store
    bus: EventBus
    gateway: FleetGateway
    dispatcher: Dispatcher
    commands: FleetCommands
    ready: bool = False
    watch: FleetWatch = field(kw_only=True)  #: what operators see of the fleet: last known states, alarms, log


@dataclass(frozen=True)
class Caller:
    """The running service and who is calling (one dependency: FastAPI's resolution is costly per level)."""

    service: Service
    principal: Principal


def get_service(request: Request) -> Service:
    service: Service | None = getattr(request.app.state, "service", None)
    if service is None:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, "the service is starting")
    return service


def _authenticate(service: Service, authorization: str | None) -> Principal:
    scheme, _, token = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token (Authorization: Bearer TOKEN)",
                            headers={"WWW-Authenticate": "Bearer"})
    principal = service.tokens.lookup(token.strip())
    if principal is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "unknown bearer token",
                            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
    return principal


def _require_operator(principal: Principal) -> None:
    if not principal.is_operator:
        raise HTTPException(status.HTTP_403_FORBIDDEN, f"{principal.name} is a {principal.role.value}: "
                                                       "this needs an operator token")


# Every dependency is async: FastAPI runs a plain function on a worker thread.
async def get_caller(request: Request) -> Caller:
    service = get_service(request)
    return Caller(service, _authenticate(service, request.headers.get("authorization")))


async def get_operator(request: Request) -> Caller:
    caller = await get_caller(request)
    _require_operator(caller.principal)
    return caller


async def get_stream_operator(request: Request, access_token: Annotated[str | None, Query(
        description="the bearer token, for clients that cannot set headers (EventSource)", max_length=512)] = None,
                              ) -> Caller:
    """An operator, by header or by ``?access_token=`` (accepted on ``/v1/events`` only)."""
    service = get_service(request)
    header = request.headers.get("authorization")
    principal = _authenticate(service, header if header or not access_token else f"Bearer {access_token}")
    _require_operator(principal)
    return Caller(service, principal)


CallerDep = Annotated[Caller, Depends(get_caller)]
OperatorDep = Annotated[Caller, Depends(get_operator)]
StreamOperatorDep = Annotated[Caller, Depends(get_stream_operator)]

#: The security scheme every /v1 operation declares in the OpenAPI document (see api.main).
BEARER_SCHEME = {"type": "http", "scheme": "bearer",
                 "description": "a token from DRONA_API_TOKENS or DRONA_API_TOKEN_FILE"}

#: Error answers every authenticated route may give, for the OpenAPI document.
AUTH_RESPONSES: dict[int | str, dict[str, object]] = {
    401: {"description": "missing or unknown bearer token"},
    403: {"description": "the token's role does not allow this"},
}
