"""``api/handlers.py``: what a 422 echoes back is JSON-safe; a 405 lists every method of its path."""

from __future__ import annotations

import json
import math

from api.handlers import json_safe
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import auth, run, running


def test_json_safe_turns_what_json_cannot_carry_into_text() -> None:
    odd = {"inf": math.inf, "nan": -math.nan, "big": 10**5000, "lone": "\ud800", "raw": b"\xff", 1: (object,),
           "fine": [1, -2.5, None, True, "é", {"k": "v"}]}
    safe = json_safe(odd)
    json.dumps(safe, allow_nan=False, ensure_ascii=False).encode("utf-8")  # raises if anything is left
    assert safe["inf"] == "inf" and safe["nan"] == "nan" and safe["big"] == "an integer of 16610 bits"
    assert safe["lone"] == "\\ud800" and safe["raw"] == "\ufffd" and safe["1"] == ["<class 'object'>"]
    assert safe["fine"] == odd["fine"]


#: (method, path, the Allow header of its 405): routes of included routers, several routes on a
#: path, a page outside /v1 and the static files.
NOT_ALLOWED = [
    ("DELETE", "/v1/mail", "GET, POST"),
    ("PUT", "/v1/mail/m-1", "GET"),
    ("GET", "/v1/mail/m-1/cancel", "POST"),
    ("POST", "/healthz", "GET"),
    ("POST", "/docs", "GET"),
    ("DELETE", "/static/app.js", "GET, HEAD"),
]


def test_a_405_lists_every_method_of_its_path(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            for method, path, allowed in NOT_ALLOWED:
                res = await h.client.request(method, path, headers=auth())
                assert (res.status_code, res.headers.get("Allow")) == (405, allowed), (method, path)

    run(body())
