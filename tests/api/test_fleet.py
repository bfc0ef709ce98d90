"""``/v1/fleet``, ``/v1/workspace``, health, the OpenAPI document and the dashboard's files."""

from __future__ import annotations

from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import auth, run, running


def test_fleet_shows_every_live_drone(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mail = await h.submit([1, 3, 0], [3, 6, 0])
            await h.service.dispatcher.idle()
            await h.steps(1)
            drones = (await h.client.get("/v1/fleet", headers=auth())).json()["drones"]
            assert [d["id"] for d in drones] == ["d1", "d2", "d3"]
            d1 = drones[0]
            assert d1["cell"] == [1, 1, 0] and d1["task"] == {"goal": [1, 3, 0], "purpose": "to_pickup",
                                                             "mail_id": mail["id"]}
            assert d1["trajectory"]["cells"][0] == [1, 1, 0] and d1["trajectory"]["cells"][-1] == [1, 3, 0]
            assert set(d1["position"]) == {"lat", "lon", "alt_m"} and 0 <= d1["battery_pct"] <= 100
            assert d1["health"] == {"ok": True, "alarms": []} and d1["alive"] is True
            h.gateway.lose("d2")
            drones = (await h.client.get("/v1/fleet", headers=auth())).json()["drones"]
            assert [d["id"] for d in drones] == ["d1", "d3"]

    run(body())


def test_workspace_gives_the_grid_with_obstacles_as_cells(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            ws = (await h.client.get("/v1/workspace", headers=auth())).json()
            assert ws["size"] == [10, 8, 1] and ws["cell_size_m"] == 1.0 and ws["tau_s"] == 1.0
            assert (ws["beta_s"], ws["lambda_s"], ws["delta"]) == (0.0, 1.882, 2)
            assert len(ws["obstacles"]) == 2 * 4 + 3 and [4, 2, 0] in ws["obstacles"] and [9, 3, 0] in ws["obstacles"]
            assert ws["charging_stations"] == [[0, 0, 0], [9, 7, 0]]
            assert ws["drones"] == {"d1": [1, 0, 0], "d2": [2, 0, 0], "d3": [8, 7, 0]}

    run(body())


def test_health_readiness_openapi_and_dashboard(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            assert (await h.client.get("/healthz")).json() == {"status": "ok"}
            ready = await h.client.get("/readyz")
            assert ready.status_code == 200 and ready.json()["ready"] is True and ready.json()["drones"] == 3
            assert ready.json()["fleet_connected"] is True
            h.gateway.opened.clear()  # the links to the fleet went down: mail taken now would reach nobody
            ready = await h.client.get("/readyz")
            assert ready.status_code == 503 and ready.json()["ready"] is False
            assert ready.json()["fleet_connected"] is False and ready.json()["drones"] == 3
            h.gateway.opened.set()
            doc = (await h.client.get("/openapi.json")).json()
            assert {"/v1/mail", "/v1/mail/{mail_id}", "/v1/mail/{mail_id}/cancel", "/v1/fleet", "/v1/workspace",
                    "/v1/events", "/healthz", "/readyz"} <= set(doc["paths"])
            post = doc["paths"]["/v1/mail"]["post"]
            assert post["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith("/MailCreate")
            assert post["security"] == [{"bearer": []}] and "422" in post["responses"]
            assert doc["components"]["schemas"]["MailCreate"]["additionalProperties"] is False
            page = await h.client.get("/")
            assert page.status_code == 200 and "<div id=\"map\"" in page.text
            assert "http" not in page.text.replace("http://www.w3.org", "")  # nothing from a CDN
            for name in ("app.js", "map.js", "panels.js", "charts.js", "style.css", "favicon.svg",
                         "vendor/leaflet/leaflet.js", "vendor/chartjs/chart.umd.min.js"):
                assert (await h.client.get(f"/static/{name}")).status_code == 200
        assert not h.service.ready  # after shutdown

    run(body())
