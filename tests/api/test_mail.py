"""``/v1/mail``: the contract of each route, strict validation naming the field, idempotency, paging, cancel."""

from __future__ import annotations

from typing import Any

import pytest

from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import SUBMITTER, auth, run, running

JSON = {"Content-Type": "application/json"}


def test_submit_answers_201_with_the_stored_mail(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            res = await h.client.post("/v1/mail", json={"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 7,
                                                        "note": "letters"}, headers=auth())
            assert res.status_code == 201
            mail = res.json()
            assert mail["id"].startswith("m-") and mail["status"] == "queued"
            assert mail["pickup"] == [1, 1, 0] and mail["dropoff"] == [7, 6, 0]
            assert mail["priority"] == 7 and mail["note"] == "letters" and mail["owner"] == "ops"
            assert mail["created_at"].endswith("Z")
            assert [e["status"] for e in mail["history"]] == ["queued"]
            got = await h.client.get(f"/v1/mail/{mail['id']}", headers=auth())
            assert got.status_code == 200 and got.json()["id"] == mail["id"]
            assert h.status(mail["id"]) == "queued"  # it is in the database

    run(body())


BAD_BODIES: list[tuple[dict[str, Any], str, str]] = [
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 3, "colour": "red"}, "colour", "extra_forbidden"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": "3"}, "priority", "int_type"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 3.0}, "priority", "int_type"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": True}, "priority", "int_type"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 10}, "priority", "less_than_equal"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": -1}, "priority", "greater_than_equal"),
    ({"pickup": [1, 1], "dropoff": [7, 6, 0], "priority": 3}, "pickup", "too_short"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0, 1], "priority": 3}, "dropoff", "too_long"),
    ({"pickup": [1, "1", 0], "dropoff": [7, 6, 0], "priority": 3}, "pickup", "int_type"),
    ({"dropoff": [7, 6, 0], "priority": 3}, "pickup", "missing"),
    ({"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 3, "note": "x" * 501}, "note", "string_too_long"),
    ({"pickup": [10, 1, 0], "dropoff": [7, 6, 0], "priority": 3}, "pickup", "out_of_bounds"),
    ({"pickup": [1, 1, 0], "dropoff": [7, -1, 0], "priority": 3}, "dropoff", "out_of_bounds"),
    ({"pickup": [4, 3, 0], "dropoff": [7, 6, 0], "priority": 3}, "pickup", "obstacle"),
    ({"pickup": [1, 1, 0], "dropoff": [9, 4, 0], "priority": 3}, "dropoff", "unreachable"),
    ({"pickup": [1, 1, 0], "dropoff": [1, 1, 0], "priority": 3}, "dropoff", "same_cell"),
]


@pytest.mark.parametrize(("payload", "field", "kind"), BAD_BODIES, ids=[f"{f}-{k}" for _, f, k in BAD_BODIES])
def test_a_bad_request_gets_422_naming_the_field_and_reason(settings: ApiSettings, workspace: Workspace,
                                                            payload: dict[str, Any], field: str, kind: str) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            res = await h.client.post("/v1/mail", json=payload, headers=auth())
            assert res.status_code == 422, res.text
            errors = res.json()["detail"]
            assert any(e["loc"][:2] == ["body", field] and e["type"] == kind and e["msg"] for e in errors), errors
            page = await h.client.get("/v1/mail", headers=auth())
            assert page.json()["items"] == []  # nothing was stored

    run(body())


def test_not_json_is_a_422(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            res = await h.client.post("/v1/mail", content=b"{not json", headers={**auth(), **JSON})
            assert res.status_code == 422
            assert res.json()["detail"][0]["type"] == "json_invalid"

    run(body())


CELLS = '"pickup": [1, 1, 0], "dropoff": [7, 6, 0]'
#: Bodies with numbers JSON cannot carry back (Python reads them as inf or nan), and where the 422 points.
NON_FINITE: list[tuple[str, list[str | int]]] = [
    (f'{{{CELLS}, "priority": 1e400}}', ["body", "priority"]),
    (f'{{{CELLS}, "priority": NaN}}', ["body", "priority"]),
    (f'{{{CELLS}, "priority": -Infinity}}', ["body", "priority"]),
    ('{"pickup": [1e999, 1, 0], "dropoff": [7, 6, 0], "priority": 3}', ["body", "pickup", 0]),
    (f'{{{CELLS}, "priority": 3, "note": 1e999}}', ["body", "note"]),
    (f'{{{CELLS}, "priority": 3, "extra": [NaN, 1e400]}}', ["body", "extra"]),
]


def test_a_number_json_cannot_carry_gets_a_422_naming_the_field(settings: ApiSettings,
                                                                 workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            for raw, loc in NON_FINITE:
                res = await h.client.post("/v1/mail", content=raw, headers={**auth(), **JSON})
                assert res.status_code == 422, (raw, res.status_code, res.text)
                error = res.json()["detail"][0]
                assert error["loc"] == loc and error["msg"], (raw, error)

    run(body())


def test_a_body_not_declared_json_gets_415(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = b'{"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 3}'
            for declared in ("text/plain", "application/x-www-form-urlencoded", "application/jsonx", None):
                headers = auth() if declared is None else {**auth(), "Content-Type": declared}
                res = await h.client.post("/v1/mail", content=mail, headers=headers)
                assert res.status_code == 415, (declared, res.status_code)
                assert "application/json" in res.json()["detail"]
            assert (await h.client.get("/v1/mail", headers=auth())).json()["items"] == []
            for declared in ("application/json", "Application/JSON; charset=utf-8"):
                res = await h.client.post("/v1/mail", content=mail, headers={**auth(), "Content-Type": declared})
                assert res.status_code == 201, (declared, res.text)

    run(body())


def test_idempotency_key_replays_and_refuses_reuse(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = {"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 2}
            key = {"Idempotency-Key": "order-42", **auth()}
            first = await h.client.post("/v1/mail", json=mail, headers=key)
            again = await h.client.post("/v1/mail", json=mail, headers=key)
            assert first.status_code == again.status_code == 201
            assert again.json()["id"] == first.json()["id"]
            assert again.headers["Idempotent-Replayed"] == "true" and "Idempotent-Replayed" not in first.headers
            other = await h.client.post("/v1/mail", json={**mail, "priority": 3}, headers=key)
            assert other.status_code == 409 and "order-42" in other.json()["detail"]
            # keys belong to their caller: another token with the same key makes its own mail
            theirs = await h.client.post("/v1/mail", json=mail, headers={"Idempotency-Key": "order-42",
                                                                          **auth(SUBMITTER)})
            assert theirs.status_code == 201 and theirs.json()["id"] != first.json()["id"]
            bad = await h.client.post("/v1/mail", json=mail, headers={"Idempotency-Key": "a b", **auth()})
            assert bad.status_code == 422 and bad.json()["detail"][0]["loc"] == ["header", "Idempotency-Key"]
            page = await h.client.get("/v1/mail", headers=auth())
            assert len(page.json()["items"]) == 2

    run(body())


def test_list_pages_newest_first_and_filters_by_status(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            ids = [(await h.submit([1, 1, 0], [7, 6, 0], priority=i))["id"] for i in range(5)]
            cancelled = await h.client.post(f"/v1/mail/{ids[1]}/cancel", headers=auth())
            assert cancelled.status_code == 200
            seen, cursor = [], None
            for _ in range(5):  # bounded: 5 mails, pages of 2
                params = {"limit": 2, **({"cursor": cursor} if cursor else {})}
                page = (await h.client.get("/v1/mail", params=params, headers=auth())).json()
                seen += [m["id"] for m in page["items"]]
                cursor = page["next_cursor"]
                if cursor is None:
                    break
            assert seen == ids[::-1]
            only = (await h.client.get("/v1/mail", params={"status": "cancelled"}, headers=auth())).json()
            assert [m["id"] for m in only["items"]] == [ids[1]]
            for params in ({"status": "lost"}, {"limit": 0}, {"limit": 501}, {"cursor": "abc"}):
                res = await h.client.get("/v1/mail", params=params, headers=auth())
                assert res.status_code == 422, params

    run(body())


def test_cancel_a_waiting_mail_but_not_a_finished_one(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            res = await h.client.post(f"/v1/mail/{mail['id']}/cancel", headers=auth())
            assert res.status_code == 200
            done = res.json()
            assert done["status"] == "cancelled" and done["reason"] == "cancelled by ops"
            assert [e["status"] for e in done["history"]][-1] == "cancelled"
            again = await h.client.post(f"/v1/mail/{mail['id']}/cancel", headers=auth())
            assert again.status_code == 409 and "cancelled" in again.json()["detail"]
            missing = await h.client.post("/v1/mail/m-nope/cancel", headers=auth())
            assert missing.status_code == 404
            assert (await h.client.get("/v1/mail/m-nope", headers=auth())).status_code == 404

    run(body())


def test_a_request_is_durable_when_acknowledged(settings: ApiSettings, workspace: Workspace) -> None:
    """Another connection to the file sees the mail as soon as the 201 is in."""
    import sqlite3

    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 1, 0], [7, 6, 0])
            with sqlite3.connect(settings.db) as other:
                row = other.execute("SELECT status FROM mail WHERE id = ?", (mail["id"],)).fetchone()
            assert row == ("queued",)

    run(body())


def test_a_database_that_fails_is_answered_503_and_loses_nothing(settings: ApiSettings,
                                                                 workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            kept = await h.submit([1, 1, 0], [7, 6, 0])
            store = h.service.store
            store._writer.execute("PRAGMA query_only = ON")  # as a disk gone read-only
            res = await h.client.post("/v1/mail", json={"pickup": [1, 1, 0], "dropoff": [7, 6, 0], "priority": 5},
                                      headers=auth())
            assert res.status_code == 503 and res.headers["Retry-After"] == "1"
            assert str(settings.db) not in res.text  # SQLite's words go to the log
            store._writer.execute("PRAGMA query_only = OFF")
            store._reader.set_authorizer(lambda *_: 1)  # SQLITE_DENY
            res = await h.client.get("/v1/mail", headers=auth())
            assert res.status_code == 503
            store._reader.set_authorizer(None)
            page = (await h.client.get("/v1/mail", headers=auth())).json()
            assert [m["id"] for m in page["items"]] == [kept["id"]]

    run(body())
