"""The service's answers to errors, shared by the app and its fast lane (:mod:`api.fastlane`).

* :func:`validation_error`: a 422 whose ``detail`` names each wrong field (``loc``) and why
  (``msg``). What it echoes back (``input``, ``ctx``) is made JSON-safe first: a body with
  ``1e400`` or ``NaN`` in it gets its 422, not a 500 from the JSON encoder.
* :func:`http_error`: FastAPI's answer, except that a 405's ``Allow`` lists every method of the path.
* :func:`store_unavailable`: a 503 when the database failed (:class:`~api.errors.StoreError`); what SQLite
  said goes to the log, not to the caller. A new mail answered so was not stored (a retry with its
  Idempotency-Key is safe); a cancel may have taken effect without its answer; a fleet command has not.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from fastapi import FastAPI, Request, Response
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import iter_route_contexts
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException

from api.errors import StoreError

log = logging.getLogger(__name__)
RETRY_AFTER_S = 1  #: a 503's Retry-After
#: What a mount of static files answers to.
STATIC_METHODS = frozenset({"GET", "HEAD"})


async def validation_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, RequestValidationError)
    return JSONResponse({"detail": json_safe(exc.errors())}, status_code=422)


async def http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    if exc.status_code == 405:
        allowed = allowed_methods(request.app, request.url.path)
        exc = HTTPException(405, exc.detail, headers={**(exc.headers or {}), "Allow": ", ".join(allowed)})
    return await http_exception_handler(request, exc)


async def store_unavailable(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, StoreError)
    log.error("%s %s: %s", request.method, request.url.path, exc)
    return JSONResponse({"detail": "the mail store cannot be read or written now: try again"}, status_code=503,
                        headers={"Retry-After": str(RETRY_AFTER_S)})


def allowed_methods(app: FastAPI, path: str) -> list[str]:
    """Every method some route of ``app`` answers on ``path`` (routers included in routers too).

    Starlette's 405 names only the methods of the first route that matched the path, and
    FastAPI's included routers hide their routes from ``app.routes``: walk them all.
    """
    methods: set[str] = set()
    for route in iter_route_contexts(app.routes):
        regex = getattr(route, "path_regex", None)
        if regex is None or not regex.fullmatch(path):
            continue
        if route.methods is not None:
            methods |= route.methods
        elif isinstance(getattr(route, "app", None), StaticFiles):
            methods |= STATIC_METHODS
    return sorted(methods)


def json_safe(value: Any) -> Any:
    """``value`` as strict JSON can carry it: what JSON cannot (inf, nan, an integer too long to
    print, a lone surrogate, an object) becomes text saying what it was."""
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, str):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(value, int):
        return _int_safe(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, bytes | bytearray):
        return value.decode("utf-8", "replace")
    if isinstance(value, dict):
        return {json_safe(str(k)): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [json_safe(v) for v in value]
    return json_safe(str(value))


def _int_safe(value: int) -> int | str:
    try:
        str(value)  # Python refuses to print an integer of more than 4,300 digits (and so does json)
    except ValueError:
        return f"an integer of {value.bit_length()} bits"
    return value
