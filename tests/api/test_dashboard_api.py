"""What the dashboard reads: the workspace on Earth, the drones' vehicles, the charts' figures, the icon."""

from __future__ import annotations

import argparse

import pytest

from api.settings import ApiSettings
from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import workspace_from_mapping
from fleet.transport.gateway import ZenohGateway
from fleet.transport.wire import DroneState, VehicleView
from tests.api.conftest import SUBMITTER, WORKSPACE, auth, run, running


def test_the_workspace_says_where_each_cell_is_on_earth(settings: ApiSettings) -> None:
    geo = {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0, "layer0_alt_m": 10.0, "layer_height_m": 5.0}
    ws = workspace_from_mapping({**WORKSPACE, "cell_size_m": 20.0, "geo_origin": geo}, source="geo.yaml")

    async def body() -> None:
        async with running(settings, ws) as h:
            out = (await h.client.get("/v1/workspace", headers=auth(SUBMITTER))).json()
            origin = out["geo_origin"]
            assert out["base_map"] is None  # none by default: nothing fetched from elsewhere
            frame = GeoFrame(ws)
            for cell in [(0, 0, 0), (9, 7, 0), (3, 5, 0)]:  # the page puts the corner (x, y) at these degrees
                centre = frame.cell_to_global(cell)
                lat = origin["lat"] + (cell[1] + 0.5) * origin["cell_dlat"]
                lon = origin["lon"] + (cell[0] + 0.5) * origin["cell_dlon"]
                assert lat == pytest.approx(centre.lat, abs=1e-9) and lon == pytest.approx(centre.lon, abs=1e-9)
            assert origin["cell_dlat"] == pytest.approx(20 / 111_200, rel=0.01)  # about 111.2 km a degree

    run(body())


def test_a_base_map_is_offered_only_when_configured(settings: ApiSettings, workspace: Workspace) -> None:
    tiles = settings.model_copy(update={"tile_url": "/tiles/{z}/{x}/{y}.png", "tile_attribution": "our tiles"})

    async def body() -> None:
        async with running(tiles, workspace) as h:
            out = (await h.client.get("/v1/workspace", headers=auth())).json()
            assert out["base_map"] == {"url": "/tiles/{z}/{x}/{y}.png", "attribution": "our tiles"}

    run(body())


def test_each_drone_shows_its_vehicle_and_coordination(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            await h.submit([1, 3, 0], [3, 6, 0])
            await h.service.dispatcher.idle()
            await h.steps(2)
            d1 = (await h.client.get("/v1/fleet", headers=auth())).json()["drones"][0]
            assert d1["vehicle"]["gps_fix"] == 3 and d1["vehicle"]["armed"] is True
            assert d1["vehicle"]["battery_v"] > 13 and d1["coordination_ms"] >= 0 and d1["seen_at"] > 0

    run(body())


def test_the_zenoh_gateway_keeps_the_vehicle_and_the_coordination_latency(workspace: Workspace) -> None:
    gateway = ZenohGateway(workspace, argparse.Namespace(fleet="t", connect=["tcp/127.0.0.1:1"], zenoh_config=None))
    vehicle = VehicleView(status="ready", mode="GUIDED", armed=True, landed="in_air", height_m=12.5, gps_fix=3,
                          satellites=11, battery_v=15.9)
    state = DroneState(drone="d1", step=4, cell=[1, 0, 0], mode="executing", phase="to_pickup", landed=False,
                       vehicle=vehicle, coordination_ms=7.25)
    view = gateway._view(state)
    assert view.coordination_ms == 7.25 and view.vehicle is not None
    assert (view.vehicle.mode, view.vehicle.armed, view.vehicle.height_m, view.vehicle.gps_fix,
            view.vehicle.satellites, view.vehicle.battery_v) == ("GUIDED", True, 12.5, 3, 11, 15.9)


def test_stats_count_deliveries_waits_by_priority_battery_and_coordination(settings: ApiSettings,
                                                                          workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            urgent = await h.submit([1, 3, 0], [3, 6, 0], priority=9)
            await h.service.dispatcher.idle()
            for _ in range(40):
                if h.status(urgent["id"]) == "delivered":
                    break
                await h.steps(1)
            assert h.status(urgent["id"]) == "delivered"
            res = await h.client.get("/v1/stats", params={"window_s": 600, "bucket_s": 60}, headers=auth())
            assert res.status_code == 200, res.text
            stats = res.json()
            assert len(stats["deliveries"]) == 10 and stats["deliveries"][-1] == 1 and sum(stats["deliveries"]) == 1
            [waited] = stats["waiting"]
            assert waited["priority"] == 9 and waited["count"] == 1 and 0 <= waited["p50_s"] <= waited["max_s"]
            assert {s["drone"] for s in stats["battery_pct"]} == {"d1", "d2", "d3"}
            assert [s["drone"] for s in stats["coordination_ms"]] == ["d1", "d1"]  # to the pickup, to the drop-off
            assert (await h.client.get("/v1/stats", headers=auth(SUBMITTER))).status_code == 403

    run(body())


def test_the_dashboard_has_an_icon(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            icon = await h.client.get("/favicon.ico")
            assert icon.status_code == 200 and icon.headers["content-type"].startswith("image/svg+xml")
            assert "<svg" in icon.text

    run(body())
