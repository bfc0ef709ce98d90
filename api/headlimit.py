"""``HeadLimit``: a request whose line and headers together pass a limit gets a 431, unanswered otherwise.

``drona serve`` runs uvicorn on h11, which refuses a request head that grows past the limit
while still incomplete (a 400, and the connection closed): a 10 MB head is never buffered.
A head that arrives whole in one read of the socket (up to a few hundred KiB) is parsed by
h11 all the same; this middleware holds it to the very same limit, exactly.
"""

from __future__ import annotations

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send


class HeadLimit:
    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and (size := head_size(scope)) > self.limit:
            response = JSONResponse({"detail": f"the request line and headers are {size} bytes: "
                                               f"at most {self.limit} are accepted"}, status_code=431)
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)


def head_size(scope: Scope) -> int:
    """The bytes of the request line and headers, as sent (give or take the method and version)."""
    target = len(scope.get("raw_path") or scope["path"].encode()) + len(scope.get("query_string", b""))
    return target + sum(len(name) + len(value) + 4 for name, value in scope["headers"])  # ": " and CRLF
