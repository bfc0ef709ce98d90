"""A fast lane for one hot route: the same endpoint, without FastAPI's router.

``POST /v1/mail`` carries the performance target (1,000 durable submissions a
second with p99 <= 50 ms on two cores). Its endpoint takes only the request and
returns a response, so it needs nothing from FastAPI's routing and dependency
machinery, which costs about as much CPU as the endpoint itself. This
middleware calls that very endpoint directly, and turns its errors into
answers with the app's own handlers (:mod:`api.handlers`), so both ways give
the same result; the route stays registered as usual, for the OpenAPI
document. It sits inside FastAPI's body-size limit and server-error
middlewares, like any user middleware.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable

from fastapi import Request, Response
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Receive, Scope, Send

from api.errors import StoreError
from api.handlers import http_error, store_unavailable, validation_error

Endpoint = Callable[[Request], Awaitable[Response]]


class FastLane:
    def __init__(self, app: ASGIApp, method: str, path: str, endpoint: Endpoint) -> None:
        self.app = app
        self.method = method
        self.path = path
        self.endpoint = endpoint

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] != self.path or scope["method"] != self.method:
            await self.app(scope, receive, send)
            return
        request = Request(scope, receive)
        try:
            response = await self.endpoint(request)
        except RequestValidationError as exc:
            response = await validation_error(request, exc)
        except HTTPException as exc:
            response = await http_error(request, exc)
        except StoreError as exc:
            response = await store_unavailable(request, exc)
        await response(scope, receive, send)
