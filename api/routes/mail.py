"""``/v1/mail``: submit, read, list and cancel mail requests."""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from api.deps import AUTH_RESPONSES, Caller, CallerDep, OperatorDep, get_caller
from api.errors import IdempotencyConflict, IllegalTransition, MailNotFound
from api.lifecycle import Status
from api.models import MAIL_CREATE_EXTRA, ErrorOut, MailCreate, MailDetail, MailPage, MailPublic
from api.store import AuditEntry, MailRecord, NewMail

router = APIRouter(prefix="/v1/mail", tags=["mail"], responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}})
_NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"model": ErrorOut, "description": "no such mail"}}
_IDEMPOTENCY_KEY = re.compile(r"[\x21-\x7e]{1,200}")


@router.post("", status_code=status.HTTP_201_CREATED, response_model=MailDetail, openapi_extra=MAIL_CREATE_EXTRA,
             responses={409: {"model": ErrorOut, "description": "the Idempotency-Key was used with another request"},
                        415: {"model": ErrorOut, "description": "the body is not declared application/json"}})
async def submit(request: Request) -> Response:
    """Submit a mail request; answered once it is stored durably.

    A retry with the same ``Idempotency-Key`` (and body) answers with the mail made the first time.
    """
    # The hot path (the performance target is on it): the only parameter is the request, so FastAPI
    # resolves nothing; the body is parsed by pydantic straight from the JSON bytes and the answer is
    # serialised once. MAIL_CREATE_EXTRA documents the body and the header as usual.
    caller = await get_caller(request)
    _require_json(request)
    key = _idempotency_key(request)
    body = _parse(await request.body())
    service = caller.service
    pickup, dropoff = _cell(body.pickup), _cell(body.dropoff)
    problems = service.checker.check(pickup, dropoff)
    if problems:
        raise RequestValidationError([{"type": p.kind, "loc": ("body", p.field), "msg": p.message,
                                       "input": getattr(body, p.field)} for p in problems])
    new = NewMail(pickup, dropoff, body.priority, body.note, caller.principal.name, key)
    try:
        record, created = await service.store.create(new)
    except IdempotencyConflict as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    history = [AuditEntry(Status.QUEUED, record.created_at, None, "")] if created else \
        service.store.history(record.seq)
    return Response(MailDetail.with_history(record, history).model_dump_json(), status.HTTP_201_CREATED,
                    None if created else {"Idempotent-Replayed": "true"}, "application/json")


def _require_json(request: Request) -> None:
    """415 unless the body is declared JSON (a charset parameter is fine): a text/plain body is
    taken for a mistake, not guessed at."""
    declared = request.headers.get("content-type")
    if declared is None or declared.partition(";")[0].strip().lower() != "application/json":
        came = f"it came as {declared}" if declared else "it came without one"
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            f"the body must be sent as Content-Type: application/json ({came})")


def _idempotency_key(request: Request) -> str | None:
    key = request.headers.get("idempotency-key")
    if key is not None and not _IDEMPOTENCY_KEY.fullmatch(key):
        raise RequestValidationError([{"type": "string_pattern_mismatch", "loc": ("header", "Idempotency-Key"),
                                       "msg": "must be 1 to 200 printable ASCII characters without spaces",
                                       "input": key}])
    return key


def _parse(raw: bytes) -> MailCreate:
    try:
        return MailCreate.model_validate_json(raw)
    except ValidationError as exc:
        raise RequestValidationError([_in_body(e) for e in exc.errors(include_url=False, include_context=False)]
                                     ) from None


def _in_body(error: Any) -> dict[str, Any]:
    """A pydantic error as FastAPI reports body errors (the body as text if it is not JSON at all)."""
    shown = error["input"]
    if isinstance(shown, bytes):
        shown = shown.decode("utf-8", errors="replace")
    return {**error, "loc": ("body", *error["loc"]), "input": shown}


@router.get("", response_model=MailPage)
async def list_mail(caller: CallerDep,
                    status_: Annotated[Status | None, Query(alias="status")] = None,
                    limit: Annotated[int, Query(ge=1, le=500)] = 50,
                    cursor: Annotated[str | None, Query(pattern=r"^[0-9]{1,18}$",
                                                        description="next_cursor of the previous page")] = None,
                    ) -> MailPage:
    """Mail, newest first (a submitter sees only its own)."""
    owner = None if caller.principal.is_operator else caller.principal.name
    before = int(cursor) if cursor is not None else None
    records = caller.service.store.page(status=status_, owner=owner, limit=limit + 1, before=before)
    more = len(records) > limit
    items = records[:limit]
    return MailPage(items=[MailPublic.of(r) for r in items], next_cursor=str(items[-1].seq) if more else None)


@router.get("/{mail_id}", response_model=MailDetail, responses=_NOT_FOUND)
async def get_mail(mail_id: str, caller: CallerDep) -> MailDetail:
    """One mail, with its audit trail."""
    record = _visible(caller, mail_id)
    return MailDetail.with_history(record, caller.service.store.history(record.seq))


@router.post("/{mail_id}/cancel", response_model=MailDetail, responses={
    **_NOT_FOUND, 409: {"model": ErrorOut, "description": "picked up or finished: it cannot be cancelled"}})
async def cancel(mail_id: str, caller: OperatorDep) -> MailDetail:
    """Cancel a mail that is not picked up yet (operators only)."""
    service = caller.service
    _visible(caller, mail_id)
    try:
        record = await service.store.transition(
            mail_id, Status.CANCELLED, reason=f"cancelled by {caller.principal.name}",
            only_from=frozenset({Status.QUEUED, Status.ASSIGNED}))
    except IllegalTransition as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    except MailNotFound as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from exc
    if record.drone is not None:
        service.dispatcher.cancel_later(record.drone, record.id)
    return MailDetail.with_history(record, service.store.history(record.seq))


def _visible(caller: Caller, mail_id: str) -> MailRecord:
    record = caller.service.store.get(mail_id)
    if record is None or not (caller.principal.is_operator or record.owner == caller.principal.name):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no mail {mail_id!r}")
    return record


def _cell(cell: list[int]) -> tuple[int, int, int]:
    return (cell[0], cell[1], cell[2])
