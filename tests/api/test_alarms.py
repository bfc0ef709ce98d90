"""``/v1/alarms`` and ``/v1/log``: alarms open and clear with the drones' states, operators acknowledge them
(stored: the audit trail), a drone that left is an alarm; and an old database is migrated at start."""

from __future__ import annotations

import sqlite3
from typing import Any

from api.alarms import kind_of, meaning_of
from api.schema import MIGRATIONS, SCHEMA
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import SUBMITTER, Harness, auth, run, running

LAG = "lag: vehicle 3.2 m from its cell"


async def alarms(h: Harness, **params: Any) -> list[dict[str, Any]]:
    await h.service.watch.alarms.settled()
    res = await h.client.get("/v1/alarms", params=params, headers=auth())
    assert res.status_code == 200, res.text
    items: list[dict[str, Any]] = res.json()["items"]
    return items


def test_an_alarm_opens_clears_and_is_acknowledged_in_the_audit_trail(settings: ApiSettings,
                                                                       workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            assert await alarms(h) == []
            h.gateway.alarms["d1"] = (LAG,)
            await h.steps(2)  # one alarm for the kind, however many states carry it
            [alarm] = await alarms(h)
            assert (alarm["drone"], alarm["kind"], alarm["text"]) == ("d1", "lag", LAG)
            assert "trails the cell its plan puts it in" in alarm["meaning"]
            assert alarm["cleared_at"] is None and alarm["acked_at"] is None
            path = f"/v1/alarms/{alarm['n']}/ack"
            assert (await h.client.post(path, headers=auth(SUBMITTER))).status_code == 403
            assert (await h.client.post("/v1/alarms/999/ack", headers=auth())).status_code == 404
            acked = await h.client.post(path, headers=auth())
            assert acked.status_code == 200 and acked.json()["acked_by"] == "ops"
            again = (await h.client.post(path, headers=auth())).json()
            assert again["acked_at"] == acked.json()["acked_at"]  # the first acknowledgement stands
            h.gateway.alarms.clear()
            await h.steps(1)
            [alarm] = await alarms(h)
            assert alarm["cleared_at"] is not None and await alarms(h, active="true") == []
            log = [e["text"] for e in (await h.client.get("/v1/log", headers=auth())).json()["items"]]
            assert log[:3] == [f"d1: alarm lag cleared: {LAG}", f"d1: alarm lag acknowledged by ops: {LAG}",
                               f"d1: alarm lag raised: {LAG}"]
        with sqlite3.connect(settings.db) as conn:  # stored: it outlives the service
            row = conn.execute("SELECT drone, kind, acked_by, cleared_at IS NOT NULL FROM alarm").fetchall()
        assert row == [("d1", "lag", "ops", 1)]

    run(body())


def test_a_drone_that_left_stays_where_last_seen_as_an_alarm_until_it_is_back(settings: ApiSettings,
                                                                             workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            await h.steps(1)
            h.gateway.freeze("d2")
            fleet = (await h.client.get("/v1/fleet", headers=auth())).json()
            assert [d["id"] for d in fleet["drones"]] == ["d1", "d3"]
            [lost] = fleet["lost"]
            assert lost["id"] == "d2" and lost["alive"] is False and lost["cell"] == [2, 0, 0] and lost["seen_at"] > 0
            [left] = await alarms(h, active="true")
            assert (left["drone"], left["kind"]) == ("d2", "left")
            h.gateway.thaw("d2")
            await h.steps(1)
            fleet = (await h.client.get("/v1/fleet", headers=auth())).json()
            assert [d["id"] for d in fleet["drones"]] == ["d1", "d2", "d3"] and fleet["lost"] == []
            assert await alarms(h, active="true") == []
            log = [e["text"] for e in (await h.client.get("/v1/log", headers=auth())).json()["items"]]
            assert "d2 is back" in log and any(t.startswith("d2 left: last seen") for t in log)

    run(body())


def test_the_log_follows_the_mail_lifecycle(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 3, 0], [3, 6, 0], priority=7)
            await h.until(lambda: h.status(mail["id"]) == "assigned")
            await h.steps(15)
            assert h.status(mail["id"]) == "delivered"
            res = await h.client.get("/v1/log", headers=auth())
            texts = [e["text"] for e in res.json()["items"] if e["mail_id"] == mail["id"]]
            assert texts[-1] == f"{mail['id']} submitted by ops, priority 7: [1, 3, 0] → [3, 6, 0]"
            assert texts[:3] == [f"{mail['id']} delivered by d1", f"{mail['id']} picked up by d1",
                                 f"{mail['id']} assigned to d1"]
            assert (await h.client.get("/v1/log", headers=auth(SUBMITTER))).status_code == 403

    run(body())


def test_an_old_database_is_migrated_at_start_and_keeps_its_mail(settings: ApiSettings, workspace: Workspace) -> None:
    with sqlite3.connect(settings.db) as conn:  # as the service before alarms left it: user_version 0
        conn.executescript(SCHEMA)
        conn.execute("INSERT INTO mail (id, owner, request_hash, px, py, pz, dx, dy, dz, priority, note, status, "
                     "drone, reason, created_at, updated_at) VALUES ('m-old', 'ops', 'h', 1, 3, 0, 3, 6, 0, 5, '', "
                     "'delivered', 'd1', '', 1.0, 2.0)")
        conn.execute("INSERT INTO audit (mail_seq, status, at, drone, reason) VALUES (1, 'delivered', 2.0, 'd1', '')")
    assert sqlite3.connect(settings.db).execute("PRAGMA user_version").fetchone() == (0,)

    async def body() -> None:
        async with running(settings, workspace) as h:
            old = (await h.client.get("/v1/mail/m-old", headers=auth())).json()
            assert old["status"] == "delivered" and old["history"][0]["drone"] == "d1"
            assert await alarms(h) == []

    run(body())
    with sqlite3.connect(settings.db) as conn:
        assert conn.execute("PRAGMA user_version").fetchone() == (len(MIGRATIONS),)
        indexes = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
        assert {"alarm_open", "audit_status_at"} <= indexes


def test_each_alarm_an_agent_raises_is_explained_to_the_operator() -> None:
    """The texts a drone's agent writes (fleet/agent): each kind has a meaning of its own, not the fallback."""
    texts = [LAG, "vehicle: came down while its plan flew", "catching up (a stall): 2 cells",
             "vehicle_lost: no HEARTBEAT", "limits: WPNAV_SPEED 100 gives 1, under the workspace's vehicle.speed_m_s",
             "clock skew: d2 is 0.7 s off"]
    meanings = [meaning_of(kind_of(text)) for text in texts]
    assert "reported by the drone" not in meanings and len(set(meanings)) == len(texts)
