"""``/v1/fleet/...`` commands over the simulated fleet: what the service does, what it tells the drones,
and the audit trail. (What the drones do: tests/drona_gcs/stack/test_drone_operator.py; over real agents:
tests/integration/test_fleet_commands.py.)"""

from __future__ import annotations

import json
from typing import Any

from api.gateway import CommandAck
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import SUBMITTER, auth, run, running


def test_a_paused_fleet_is_handed_no_mail_until_resumed(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            res = await h.client.post("/v1/fleet/pause", headers=auth())
            assert res.status_code == 200, res.text
            record = res.json()
            assert record["action"] == "pause" and record["by"] == "ops" and record["drone"] is None
            assert {a["drone"] for a in record["acks"]} == {"d1", "d2", "d3"}
            mail = await h.submit([1, 3, 0], [3, 6, 0])
            await h.steps(3)
            history = (await h.client.get(f"/v1/mail/{mail['id']}", headers=auth())).json()["history"]
            assert [e["status"] for e in history] == ["queued"]  # never even offered
            assert h.gateway.assigned == []
            assert (await h.client.post("/v1/fleet/resume", headers=auth())).status_code == 200
            await h.until(lambda: h.status(mail["id"]) != "queued")
            assert h.gateway.commands == [(None, "pause", "ops"), (None, "resume", "ops")]

    run(body())


def test_a_recalled_drone_hands_its_mail_back_and_gets_none_until_resumed(
        settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            h.gateway.refusing.update({"d2": "busy", "d3": "busy"})  # only d1 takes the mail
            mail = await h.submit([1, 3, 0], [3, 6, 0])
            await h.until(lambda: h.status(mail["id"]) == "assigned")
            await h.service.dispatcher.idle()  # d1 has it
            assert h.gateway.assigned == [("d1", mail["id"])]
            res = await h.client.post("/v1/fleet/drones/d1/recall", headers=auth())
            assert res.status_code == 200 and res.json()["acks"] == [{"drone": "d1", "accepted": True, "reason": ""}]
            await h.until(lambda: h.status(mail["id"]) == "queued")  # handed back by d1, and not to it again
            history = (await h.client.get(f"/v1/mail/{mail['id']}", headers=auth())).json()["history"]
            assert history[-1]["reason"] == "drone d1 rejected it: recall by ops"
            assert "d1" in h.service.dispatcher.held
            later = await h.submit([2, 3, 0], [3, 5, 0])
            await h.steps(2)
            history = (await h.client.get(f"/v1/mail/{later['id']}", headers=auth())).json()["history"]
            assert all(e["drone"] != "d1" for e in history)  # never offered to the recalled drone
            assert (await h.client.post("/v1/fleet/drones/d1/resume", headers=auth())).status_code == 200
            assert "d1" not in h.service.dispatcher.held

    run(body())


def test_commands_are_recorded_with_who_asked_and_checked(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            assert (await h.client.post("/v1/fleet/drones/d9/land", headers=auth())).status_code == 404
            assert (await h.client.post("/v1/fleet/pause", headers=auth(SUBMITTER))).status_code == 403
            h.gateway.silent.add("d2")
            late = await h.client.post("/v1/fleet/drones/d2/land", headers=auth())
            assert late.status_code == 504 and "did not answer" in late.json()["detail"]
            assert (await h.client.post("/v1/fleet/drones/d3/land", headers=auth())).status_code == 200
            history = (await h.client.get("/v1/fleet/commands", headers=auth())).json()
            assert [(c["action"], c["drone"], c["by"], len(c["acks"])) for c in history] == [
                ("land", "d3", "ops", 1), ("land", "d2", "ops", 0)]
            assert h.service.dispatcher.held == {"d2", "d3"}

    run(body())


def test_a_restarted_service_keeps_the_fleet_paused_and_the_drones_held(
        settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            for path in ("/v1/fleet/pause", "/v1/fleet/drones/d2/land", "/v1/fleet/drones/d3/recall",
                         "/v1/fleet/drones/d3/resume"):
                assert (await h.client.post(path, headers=auth())).status_code == 200
        async with running(settings, workspace) as h:  # the same database
            assert h.service.dispatcher.paused and h.service.dispatcher.held == {"d2"}
            assert (await h.client.post("/v1/fleet/resume", headers=auth())).status_code == 200
        async with running(settings, workspace) as h:
            assert not h.service.dispatcher.paused and h.service.dispatcher.held == set()

    run(body())


def test_every_command_goes_out_on_the_event_stream(settings: ApiSettings, workspace: Workspace) -> None:
    """Other operators' pages learn of a command at once (``command`` events on /v1/events)."""
    async def body() -> None:
        async with running(settings, workspace) as h:
            with h.service.bus.subscribe() as sub:
                assert (await h.client.post("/v1/fleet/drones/d1/recall", headers=auth())).status_code == 200
                events = [sub.queue.get_nowait() for _ in range(sub.queue.qsize())]
            commands = [json.loads(e.data) for e in events if e is not None and e.kind == "command"]
            assert [(c["action"], c["drone"], c["by"]) for c in commands] == [("recall", "d1", "ops")]

    run(body())


def test_a_drone_gone_from_the_fleet_is_released_only_while_it_is_gone(
        settings: ApiSettings, workspace: Workspace) -> None:
    """``release`` tells every live drone to stop holding the cells a departed drone may have stopped
    on, once the operator saw its vehicle out of the air; refused for a drone in the fleet."""
    async def body() -> None:
        async with running(settings, workspace) as h:
            res = await h.client.post("/v1/fleet/drones/d2/release", headers=auth())
            assert res.status_code == 409 and "in the fleet" in res.json()["detail"]
            assert h.gateway.commands == []
            h.gateway.lose("d2")
            res = await h.client.post("/v1/fleet/drones/d2/release", headers=auth())
            assert res.status_code == 200, res.text
            assert res.json()["action"] == "release" and res.json()["drone"] == "d2"
            assert {a["drone"] for a in res.json()["acks"]} == {"d1", "d3"}
            assert h.gateway.commands == [(None, "release", "ops", "d2")]
            history = (await h.client.get("/v1/fleet/commands", headers=auth())).json()
            assert [(c["action"], c["drone"], c["by"]) for c in history] == [("release", "d2", "ops")]
            assert (await h.client.post("/v1/fleet/drones/d9/release", headers=auth())).status_code == 404

    run(body())


def test_a_command_the_database_refuses_does_nothing(settings: ApiSettings, workspace: Workspace) -> None:
    """Recorded before it takes effect: a 503 means the fleet was neither told nor held."""
    async def body() -> None:
        async with running(settings, workspace) as h:
            h.service.store._writer.execute("PRAGMA query_only = ON")  # as a disk gone read-only
            res = await h.client.post("/v1/fleet/pause", headers=auth())
            assert res.status_code == 503, res.text
            assert (await h.client.post("/v1/fleet/drones/d1/land", headers=auth())).status_code == 503
            assert h.gateway.commands == [] and not h.service.dispatcher.paused
            assert h.service.dispatcher.held == set()
            h.service.store._writer.execute("PRAGMA query_only = OFF")
            assert (await h.client.get("/v1/fleet/commands", headers=auth())).json() == []

    run(body())


def disk_fails_once_told(h: Any) -> None:
    """The database goes read-only right after the drones heard a command."""
    tell = h.gateway.command

    async def told_then_disk_fails(*args: Any, **kwargs: Any) -> list[CommandAck]:
        acks: list[CommandAck] = await tell(*args, **kwargs)
        h.service.store._writer.execute("PRAGMA query_only = ON")
        return acks

    h.gateway.command = told_then_disk_fails


def test_a_command_whose_answers_were_not_stored_says_so(settings: ApiSettings, workspace: Workspace) -> None:
    """The database fails after the drones were told: the command stands, recorded, its answers missing."""
    async def body() -> None:
        async with running(settings, workspace) as h:
            disk_fails_once_told(h)
            res = await h.client.post("/v1/fleet/drones/d1/land", headers=auth())
            assert res.status_code == 200, res.text
            assert res.json()["answered"] is False and res.json()["acks"][0]["drone"] == "d1"
            h.service.store._writer.execute("PRAGMA query_only = OFF")
            assert h.service.dispatcher.held == {"d1"}
            history = (await h.client.get("/v1/fleet/commands", headers=auth())).json()
            assert [(c["action"], c["drone"], c["answered"], c["acks"]) for c in history] == [
                ("land", "d1", False, [])]

    run(body())


def test_a_release_the_drones_heard_is_answered_even_if_the_database_then_fails(
        settings: ApiSettings, workspace: Workspace) -> None:
    """Every live drone already stopped holding the gone drone's cells: not a 503 (which says nothing
    was done); the gone drone's mail is given up at its deadline instead."""
    async def body() -> None:
        async with running(settings, workspace) as h:
            h.gateway.refusing.update({"d1": "busy", "d3": "busy"})  # only d2 takes the mail
            mail = await h.submit([1, 3, 0], [3, 6, 0])
            for _ in range(40):  # bounded: the pickup is a few cells away
                if h.status(mail["id"]) == "picked_up":
                    break
                await h.steps(1)
            assert h.status(mail["id"]) == "picked_up"
            h.gateway.lose("d2")
            disk_fails_once_told(h)
            res = await h.client.post("/v1/fleet/drones/d2/release", headers=auth())
            assert res.status_code == 200, res.text
            assert res.json()["answered"] is False and {a["drone"] for a in res.json()["acks"]} == {"d1", "d3"}
            assert h.status(mail["id"]) == "picked_up"  # not failed yet: the database refused
            h.service.store._writer.execute("PRAGMA query_only = OFF")

    run(body())
