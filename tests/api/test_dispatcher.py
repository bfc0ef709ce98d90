"""The dispatcher against the simulated fleet: delivery, order, lost drones, silence, refusals, restarts."""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

import pytest

from api.gateway import MailStatusReport
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import auth, run, running
from tests.api.simulated import SimulatedGateway


def history(mail: dict[str, Any]) -> list[tuple[object, object]]:
    return [(e["status"], e["drone"]) for e in mail["history"]]


def test_a_mail_is_assigned_picked_up_and_delivered(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 2, 0], [3, 6, 0])
            await h.service.dispatcher.idle()
            assert h.status(mail["id"]) == "assigned"
            await h.steps(20)  # d1 at [1, 0, 0]: 2 steps to the pickup, then 6 to the drop-off
            done = (await h.client.get(f"/v1/mail/{mail['id']}", headers=auth())).json()
            assert done["status"] == "delivered"
            assert history(done) == [("queued", None), ("assigned", "d1"), ("picked_up", "d1"), ("delivered", "d1")]
            assert h.gateway.cleared == [("d1", mail["id"])]  # once it started: before, a loss requeues it
            stamps = [e["at"] for e in done["history"]]
            assert stamps == sorted(stamps)

    run(body())


def test_waiting_mail_goes_out_by_priority_then_age(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        gateway = SimulatedGateway(workspace, drones=1, step_s=None)
        async with running(settings.model_copy(update={"per_drone": 1}), workspace, gateway) as h:
            first = await h.submit([1, 1, 0], [2, 1, 0], priority=0)
            await h.service.dispatcher.idle()
            assert gateway.assigned == [("sim1", first["id"])]
            ids = {name: (await h.submit([1, 1, 0], [2, 1, 0], priority=p))["id"]
                   for name, p in (("low", 1), ("urgent", 9), ("mid", 5), ("urgent2", 9))}
            await h.service.dispatcher.idle()
            assert len(gateway.assigned) == 1  # the one drone is busy
            await h.steps(150)
            assert [m for _, m in gateway.assigned[1:]] == [ids["urgent"], ids["urgent2"], ids["mid"], ids["low"]]
            assert all(h.status(i) == "delivered" for i in ids.values())

    run(body())


def test_the_nearest_idle_drone_takes_it(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            near_d3 = await h.submit([8, 6, 0], [6, 6, 0])
            await h.service.dispatcher.idle()
            assert h.gateway.assigned == [("d3", near_d3["id"])]

    run(body())


def test_a_lost_drone_s_mail_not_cleared_is_requeued_and_what_it_may_carry_waits_for_its_release(
        settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        quick = settings.model_copy(update={"assign_timeout_s": 0.5})
        async with running(quick, workspace) as h:
            on_board = await h.submit([1, 1, 0], [1, 7, 0])  # d1, one step away
            await h.service.dispatcher.idle()
            await h.steps(2)
            assert h.status(on_board["id"]) == "picked_up"
            started = await h.submit([7, 1, 0], [7, 6, 0])  # d2 now: d1 is busy
            await h.service.dispatcher.idle()
            await h.steps(1)  # d2 starts it: cleared for pickup
            waiting = await h.submit([2, 2, 0], [2, 6, 0])  # d3 now, not started
            await h.service.dispatcher.idle()
            assert [h.drone_of(m["id"]) for m in (started, waiting)] == ["d2", "d3"]
            assert ("d2", started["id"]) in h.gateway.cleared and ("d3", waiting["id"]) not in h.gateway.cleared
            for drone in ("d1", "d2", "d3"):
                h.gateway.lose(drone)
            await h.service.dispatcher.idle()
            assert h.status(waiting["id"]) == "queued"  # d3 may not take it on board: it is no longer its own
            # d1 and d2 may be only cut off, and deliver: no deadline runs out on what they may carry.
            await asyncio.sleep(3 * quick.assign_timeout_s)  # past every deadline: nothing may happen
            await h.service.dispatcher.idle()
            assert h.status(on_board["id"]) == "picked_up" and h.status(started["id"]) == "assigned"
            for drone, mail in (("d1", on_board), ("d2", started)):
                res = await h.client.post(f"/v1/fleet/drones/{drone}/release", headers=auth())
                assert res.status_code == 200, res.text
                failed = h.service.store.get(mail["id"])
                assert failed is not None and failed.status.value == "failed"
                assert f"{drone} was released by the operator" in failed.reason and "on board" in failed.reason

    run(body())


def test_mail_cleared_to_a_drone_whose_agent_restarted_without_it_fails_and_goes_to_nobody_else(
        settings: ApiSettings, workspace: Workspace) -> None:
    """Its vehicle may carry it, the pickup report lost with the old agent: given again, the mail would
    have two owners. Mail the drone was never cleared for goes to another drone as before."""
    async def body() -> None:
        quick = settings.model_copy(update={"assign_timeout_s": 0.5})
        async with running(quick, workspace) as h:
            started = await h.submit([7, 1, 0], [7, 6, 0])
            await h.service.dispatcher.idle()
            drone = h.drone_of(started["id"])
            await h.steps(1)  # started: cleared for pickup
            assert drone is not None and (drone, started["id"]) in h.gateway.cleared
            h.gateway.freeze(drone)
            await h.service.dispatcher.idle()
            h.gateway.restart(drone)
            await h.steps(1)  # back, its new agent knowing nothing of the mail
            await h.until(lambda: h.status(started["id"]) == "failed", timeout=10)
            failed = h.service.store.get(started["id"])
            assert failed is not None and "may have had the mail on board" in failed.reason
            assert failed.drone == drone

    run(body())


def test_reports_from_unknown_drones_or_about_unknown_mail_are_ignored(
        settings: ApiSettings, workspace: Workspace, caplog: pytest.LogCaptureFixture) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            await h.service.dispatcher.idle()
            holder = h.gateway.assigned[0][0]
            other = "d3" if holder != "d3" else "d1"
            for report in (MailStatusReport(mail["id"], "ghost", "delivered", at=time.time()),
                           MailStatusReport("m-unknown", holder, "delivered", at=time.time()),
                           MailStatusReport(mail["id"], other, "picked_up", at=time.time())):
                h.gateway.report(report)
            await h.service.dispatcher.idle()
            assert h.status(mail["id"]) == "assigned"

    with caplog.at_level(logging.INFO, logger="api.dispatcher"):
        run(body())
    text = caplog.text
    assert "unknown drone" in text and "unknown mail" in text and "holds that mail" in text


def test_a_drone_that_never_mentions_its_mail_does_not_keep_it(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        quick = settings.model_copy(update={"assign_timeout_s": 0.3, "refuse_backoff_s": 30.0})
        gateway = SimulatedGateway(workspace, step_s=0.02)  # flying on its own, publishing its state
        async with running(quick, workspace, gateway) as h:
            gateway.silent.add("d1")
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            await h.until(lambda: h.status(mail["id"]) == "delivered", timeout=10)
            assert [d for d, _ in gateway.assigned] == ["d1", "d2"]  # requeued after 0.3 s, then to d2
            assert ("d1", mail["id"]) in gateway.cancelled
            trail = h.service.store.history(h.record(mail["id"]).seq)
            assert any(e.status.value == "queued" and "d1 stopped reporting" in e.reason for e in trail)

    run(body())


def test_a_refusing_drone_is_passed_over(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            h.gateway.refusing["d1"] = "battery service due"
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            record = h.record(mail["id"])
            await h.until(lambda: (h.service.store.get(mail["id"]) or record).drone == "d2", timeout=5)
            await h.service.dispatcher.idle()
            assert [d for d, _ in h.gateway.assigned] == ["d2"]
            trail = h.service.store.history(h.record(mail["id"]).seq)
            assert any("battery service due" in e.reason for e in trail)

    run(body())


def test_a_rejection_is_for_a_while_and_mail_every_drone_rejects_again_and_again_fails(
        settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        gateway = SimulatedGateway(workspace, drones=1, step_s=None)
        quick = settings.model_copy(update={"refuse_backoff_s": 0.1, "max_rejections": 3})
        async with running(quick, workspace, gateway) as h:
            gateway.silent.add("sim1")
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            offered_at = []
            for times in range(1, 4):
                await h.until(lambda: h.status(mail["id"]) == "assigned", timeout=5)
                offered_at.append(time.monotonic())
                await h.service.dispatcher.idle()
                assert len(gateway.assigned) == times
                gateway.report(MailStatusReport(mail["id"], "sim1", "rejected", "needs 99 steps", at=time.time()))
                await h.service.dispatcher.idle()
            record = h.service.store.get(mail["id"])
            assert record is not None and record.status.value == "failed"
            assert "every drone rejected it 3 time(s)" in record.reason and "needs 99 steps" in record.reason
            assert gateway.assigned == [("sim1", mail["id"])] * 3
            assert offered_at[2] - offered_at[1] >= 0.2  # the backoff doubled

    run(body())


def test_cancelling_an_assigned_mail_tells_its_drone(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 1, 0], [3, 1, 0])
            await h.service.dispatcher.idle()
            res = await h.client.post(f"/v1/mail/{mail['id']}/cancel", headers=auth())
            assert res.status_code == 200 and res.json()["status"] == "cancelled"
            await h.service.dispatcher.idle()
            assert h.gateway.cancelled == [("d1", mail["id"])]
            await h.steps(10)
            assert h.status(mail["id"]) == "cancelled"  # the drone dropped it: no late delivery

    run(body())


def test_unfinished_mail_resumes_after_a_restart(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        gateway = SimulatedGateway(workspace, drones=1, step_s=None)
        async with running(settings.model_copy(update={"per_drone": 1}), workspace, gateway) as h:
            gateway.silent.add("sim1")
            held = await h.submit([1, 1, 0], [3, 1, 0])
            waiting = await h.submit([1, 1, 0], [3, 2, 0])
            await h.service.dispatcher.idle()
            assert h.status(held["id"]) == "assigned" and h.status(waiting["id"]) == "queued"
        # the service is gone; the drone never heard of the mail. A new service, a working fleet:
        quick = settings.model_copy(update={"assign_timeout_s": 0.3})
        async with running(quick, workspace, SimulatedGateway(workspace, step_s=0.02)) as h:
            await h.until(lambda: h.status(held["id"]) == h.status(waiting["id"]) == "delivered", timeout=10)
            trail = h.service.store.history(h.record(held["id"]).seq)
            assert any(e.status.value == "queued" and "sim1 stopped reporting" in e.reason for e in trail)

    run(body())


def test_a_database_failing_under_a_dispatch_round_is_survived_and_the_round_tried_again(
        settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            dispatcher, store = h.service.dispatcher, h.service.store
            dispatcher.hold(paused=True)
            mail = await h.submit([1, 1, 0], [7, 6, 0])
            store._writer.execute("PRAGMA query_only = ON")  # as a disk gone read-only
            dispatcher.hold(paused=False)  # the round's assignment fails
            await asyncio.sleep(0.2)
            assert h.status(mail["id"]) == "queued"
            store._writer.execute("PRAGMA query_only = OFF")
            await h.until(lambda: h.status(mail["id"]) == "assigned", timeout=5.0)

    run(body())
