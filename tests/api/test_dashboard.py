"""The dashboard in headless Chromium (Debian's ``chromium``, driven by Playwright), as an operator uses it.

The service runs in this process (tests/api/served.py) so that the test can act on the simulated fleet
while the page watches. Screenshots go to the folder each test prints, for a person to look at. Every
request the page makes must go to the service itself, and no script may fail.
Skipped, with the reason printed, when Chromium or Playwright is missing (``apt-get install chromium``).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.settings import ApiSettings
from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import workspace_from_mapping
from tests.api.conftest import OPERATOR, WORKSPACE, auth
from tests.api.served import Served

GEO = {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0, "layer0_alt_m": 10.0, "layer_height_m": 5.0}
#: The API tests' grid, two layers high, 10 m cells, near Zurich: the wall blocks both layers, [7, 6] the upper only.
BROWSER_WS = {**WORKSPACE, "size": [10, 8, 2], "cell_size_m": 10.0, "geo_origin": GEO,
              "obstacles": [{"box": [[4, 2, 0], [5, 5, 1]]}, [9, 3, 0], [8, 4, 0], [9, 5, 0], [7, 6, 1]]}
LAG = "lag: vehicle 3.2 m from its cell"
NEW_TOKEN = "operator-token-after-restart-0123"

#: Every visible drone label and the map's box, in page pixels.
LABEL_BOXES = """() => {
  const box = (el) => { const r = el.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; };
  const labels = [...document.querySelectorAll('#map .labels .label')].filter((el) => !el.hidden);
  const controls = [...document.querySelectorAll('#map .leaflet-control')].map((el) => [el.className, ...box(el)]);
  return { map: box(document.getElementById('map')), labels: labels.map((el) => [el.dataset.id, ...box(el)]),
           controls };
}"""
#: The page's scroll width if over its viewport's, and each element reaching past it (but Leaflet's panes and
#: the mail table, which their boxes clip or scroll).
WIDER_THAN_THE_PAGE = """() => {
  const width = document.documentElement.clientWidth, over = [];
  if (document.documentElement.scrollWidth > width) over.push(`page ${document.documentElement.scrollWidth}`);
  for (const el of document.querySelectorAll('body *')) {
    const right = el.getBoundingClientRect().right;
    if (right > width && !el.closest('.leaflet-container, .table-wrap')) over.push(`${el.tagName}#${el.id} ${right}`);
  }
  return over;
}"""
#: Where the page draws a drone's dot, and where Leaflet puts the given latitude and longitude.
DRAWN_AT = """([id, lat, lon]) => {
  const dot = document.querySelector(`#map path.drone[data-id="${id}"]`).getBoundingClientRect();
  const map = document.getElementById('map').getBoundingClientRect();
  const p = drona.leaflet.latLngToContainerPoint([lat, lon]);
  return [dot.left + dot.width / 2 - map.left, dot.top + dot.height / 2 - map.top, p.x, p.y];
}"""


@dataclass
class Watched:
    """What a page did: its requests, failed responses, and errors."""

    requests: list[str] = field(default_factory=list)
    failed: list[tuple[int, str]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def attach(self, page: Any) -> None:
        page.on("request", lambda r: self.requests.append(r.url))
        page.on("response", lambda r: self.failed.append((r.status, r.url)) if r.status >= 400 else None)
        page.on("pageerror", lambda exc: self.errors.append(f"page error: {exc}"))
        page.on("console", lambda m: self.errors.append(f"console: {m.text}") if m.type == "error" else None)

    def check(self, origin: str, expected: frozenset[tuple[int, str]] = frozenset()) -> None:
        """Nothing from elsewhere, no script error, and no failed response but the ``expected`` (status, path):
        the browser logs each of those as a console error, "Failed to load resource"."""
        foreign = [u for u in self.requests if not u.startswith(origin + "/")]
        assert foreign == [], f"requests leaving the service: {foreign}"
        assert [e for e in self.errors if "Failed to load resource" not in e] == [], self.errors
        failed = {(status, url.removeprefix(origin).split("?")[0]) for status, url in self.failed}
        assert failed <= expected, f"failed responses: {sorted(failed - expected)}"


@pytest.fixture
def geo_workspace() -> Workspace:
    return workspace_from_mapping(BROWSER_WS, source="browser.yaml")


@pytest.fixture
def screenshots(tmp_path: Path) -> Path:
    folder = tmp_path / "screenshots"
    folder.mkdir()
    print(f"screenshots of the dashboard: {folder}")
    return folder


@pytest.fixture
def served(settings: ApiSettings, geo_workspace: Workspace) -> Iterator[Served]:
    service = Served(settings, geo_workspace)
    yield service
    service.stop()


#: The element a selector finds now, and a count of the page's draws from now on.
KEEP_ELEMENT = """(selector) => {
  window.keptElement = document.querySelector(selector);
  window.draws = 0;
  const draw = drona.panels.draw;
  drona.panels.draw = (...args) => { window.draws += 1; return draw(...args); };
}"""


def assert_kept_through_draws(page: Any, selector: str) -> None:
    """The page draws on every state: a button rebuilt between a click's press and release loses it."""
    page.evaluate(KEEP_ELEMENT, selector)
    page.wait_for_function("window.draws >= 5", timeout=10_000)
    assert page.evaluate(f"document.querySelector({selector!r}) === window.keptElement"), f"{selector} rebuilt"


def open_dashboard(browser: Any, served: Served, watched: Watched, width: int = 1400) -> Any:
    page = browser.new_page(viewport={"width": width, "height": 900})
    watched.attach(page)
    page.goto(served.url + "/")
    page.wait_for_selector("#token-panel:not([hidden])")
    page.fill("#token", OPERATOR)
    page.click("#token-form button")
    page.wait_for_selector("#conn[data-state='live']", timeout=10_000)
    page.wait_for_function("document.querySelectorAll('#map path.drone').length === 3", timeout=10_000)
    return page


def assert_labels_apart(page: Any, expect_all: bool = True) -> None:
    boxes = page.evaluate(LABEL_BOXES)
    left, top, right, bottom = boxes["map"]
    labels = boxes["labels"]
    if expect_all:
        assert sorted(label[0] for label in labels) == ["d1", "d2", "d3"]
    for name, x0, y0, x1, y1 in labels:
        assert left <= x0 and x1 <= right and top <= y0 and y1 <= bottom, f"{name}'s label is clipped"
    for i, a in enumerate(labels):
        for b in labels[i + 1:] + boxes["controls"]:
            apart = a[3] <= b[1] or b[3] <= a[1] or a[4] <= b[2] or b[4] <= a[2]
            assert apart, f"the label of {a[0]} overlaps {b[0]}'s"


def submit(page: Any, pickup: tuple[int, int, int], dropoff: tuple[int, int, int], priority: int) -> str:
    for prefix, cell in (("p", pickup), ("d", dropoff)):
        for axis, value in zip("xyz", cell, strict=True):
            page.fill(f"#mail-form [name='{prefix}{axis}']", str(value))
    page.fill("#mail-form [name='priority']", str(priority))
    page.click("#mail-form button")
    page.wait_for_selector("#form-msg[data-kind='ok'], #form-msg[data-kind='error']", timeout=10_000)
    return str(page.locator("#form-msg").inner_text())


def test_the_operator_sees_the_fleet_on_its_map_and_handles_alarms(browser: Any, served: Served,
                                                                   geo_workspace: Workspace,
                                                                   screenshots: Path) -> None:
    watched = Watched()
    page = open_dashboard(browser, served, watched)
    # The map on geographic coordinates: each drone where GeoFrame puts its cell, with scale, north, lat/lon.
    frame = GeoFrame(geo_workspace)
    for drone, cell in geo_workspace.drones.items():
        where = frame.cell_to_global(cell)
        x, y, want_x, want_y = page.evaluate(DRAWN_AT, [drone, where.lat, where.lon])
        assert abs(x - want_x) < 1.5 and abs(y - want_y) < 1.5, f"{drone} drawn at {x, y}, not {want_x, want_y}"
    assert page.locator("#map path.obstacle:not(.other-layer)").count() == 11  # the wall and three cells
    upper = page.locator("#map path.obstacle.other-layer")
    assert upper.count() == 1 and upper.get_attribute("data-top") == "17.5"  # layer 1: 15 m, + half a layer
    assert page.locator("#map path.charger").count() == 2 and page.locator("#map path.parking").count() == 2
    assert page.locator(".leaflet-control-scale-line").inner_text().endswith("m")
    assert page.locator("#map .north").count() == 1 and "47.397742° N" in page.locator("#origin").inner_text()
    page.hover("#map", position={"x": 300, "y": 200})
    assert re.fullmatch(r"47\.\d{6}° N 8\.\d{6}° E · cell \[\d, \d, 0\]", page.locator("#map .coords").inner_text())
    assert_labels_apart(page)
    # A mail flies: the plan and the flown track are drawn; once delivered its markers leave the map.
    mail_id = submit(page, (1, 3, 0), (3, 6, 0), 8).split()[0]
    page.wait_for_selector(f"#map path.marker.pickup[data-id='{mail_id}']", state="attached")
    page.wait_for_selector("#map path.traj[data-drone='d1']", state="attached", timeout=10_000)
    page.wait_for_function("Number(document.querySelector(\"#map path.track[data-drone='d1']\")"
                           "?.dataset.points) >= 4", timeout=10_000)
    page.screenshot(path=str(screenshots / "flying.png"))
    page.wait_for_selector(f"#mail tr[data-id='{mail_id}'][data-status='delivered']", timeout=20_000)
    assert page.locator(f"#map path.marker[data-id='{mail_id}']").count() == 0
    assert "delivered by d1" in page.locator("#log").inner_text()
    # d2's link goes: it stays where it was, stale with the time since, and is live again when it is back.
    before = page.evaluate(DRAWN_AT, ["d2", 0, 0])[:2]
    served.call(served.gateway.freeze, "d2")
    page.wait_for_selector("#map path.drone.stale[data-id='d2']", timeout=10_000)
    assert page.evaluate(DRAWN_AT, ["d2", 0, 0])[:2] == before
    page.wait_for_function("/stale [0-9]+ s/.test(document.querySelector(\"#map .label[data-id='d2']\").textContent)")
    assert page.locator("#drones li[data-id='d2']").get_attribute("data-stale") == "true"
    page.wait_for_selector("#alarms li[data-active='true'] >> text=left", timeout=10_000)
    assert_labels_apart(page, expect_all=False)
    page.screenshot(path=str(screenshots / "stale.png"))
    served.call(served.gateway.thaw, "d2")
    page.wait_for_selector("#map path.drone[data-id='d2'][data-stale='false']", timeout=10_000)
    # An alarm: raised with its meaning, acknowledged by the operator, and recorded as such.
    served.call(served.gateway.alarms.__setitem__, "d1", (LAG,))
    alarm = page.locator("#alarms li[data-active='true'][data-acked='false']", has_text="lag")
    alarm.wait_for(timeout=10_000)
    assert "trails the cell its plan puts it in" in alarm.inner_text()
    page.screenshot(path=str(screenshots / "alarm.png"))
    assert_kept_through_draws(page, "#alarms button.ack")
    alarm.locator("button.ack").click()
    page.wait_for_selector("#alarms li[data-acked='true'] >> text=acknowledged by ops", timeout=10_000)
    page.wait_for_selector("#log li >> text=alarm lag acknowledged by ops", timeout=10_000)
    # The charts have the delivery; "live" means the fleet is reachable, not only the page's stream.
    page.evaluate("drona.charts.refresh()")
    page.wait_for_function("Chart.getChart('c-deliveries').data.datasets[0].data.reduce((a, b) => a + b, 0) >= 1")
    served.call(served.gateway.opened.clear)
    page.wait_for_selector("#conn[data-state='degraded']", timeout=10_000)
    assert page.locator("#conn").inner_text() == "fleet unreachable"
    served.call(served.gateway.opened.set)
    page.wait_for_selector("#conn[data-state='live']", timeout=10_000)
    # An error gives way to the next answer.
    assert "is on an obstacle" in submit(page, (4, 3, 0), (3, 6, 0), 5)
    assert submit(page, (1, 3, 0), (3, 6, 0), 5).endswith("queued")
    page.screenshot(path=str(screenshots / "desktop.png"), full_page=True)
    watched.check(served.url, frozenset({(503, "/readyz"), (422, "/v1/mail")}))
    page.close()


def test_the_page_fits_a_phone_and_asks_for_the_token_after_a_restart(browser: Any, settings: ApiSettings,
                                                                      geo_workspace: Workspace,
                                                                      screenshots: Path) -> None:
    served = Served(settings, geo_workspace)
    watched = Watched()
    try:
        page = open_dashboard(browser, served, watched, width=390)
        page.wait_for_selector("#charts-panel[data-updated]", timeout=10_000)
        assert page.evaluate(WIDER_THAN_THE_PAGE) == [], "wider than the phone"
        assert_labels_apart(page, expect_all=False)
        page.screenshot(path=str(screenshots / "phone.png"), full_page=True)
        watched.check(served.url)
        # The service restarts with other tokens: the page asks for one instead of reconnecting forever.
        served.stop()
        new = settings.model_copy(update={"tokens": f"operator:{NEW_TOKEN}:night"})
        served = Served(new, geo_workspace, port=served.port)
        page.wait_for_selector("#token-panel:not([hidden])", timeout=15_000)
        assert page.locator("#conn").inner_text() == "token refused"
        assert "enter it again" in page.locator("#token-msg").inner_text()
        page.screenshot(path=str(screenshots / "token-refused.png"))
        page.fill("#token", NEW_TOKEN)
        page.click("#token-form button")
        page.wait_for_selector("#conn[data-state='live']", timeout=10_000)
        page.wait_for_function("document.querySelectorAll('#map path.drone').length === 3", timeout=10_000)
        assert page.locator("#token-panel").is_hidden()
        page.screenshot(path=str(screenshots / "after-restart.png"))
        # The old token's 401s failed, and the loads while the service was down (no response at all).
        refused = frozenset((401, path) for path in ("/v1/events", "/v1/workspace", "/v1/fleet", "/v1/stats"))
        watched.check(served.url, refused)
        page.close()
    finally:
        served.stop()


def command_outcome(page: Any, drone: str) -> Any:
    """The outcome line in ``drone``'s item of the drone list, once a command's answer is in."""
    outcome = page.locator(f"#drones li[data-id='{drone}'] .outcome[data-kind='ok'], "
                           f"#drones li[data-id='{drone}'] .outcome[data-kind='error']")
    outcome.wait_for(timeout=10_000)
    return outcome


def confirm_command(page: Any, served: Served, drone: str, action: str) -> None:
    """``action`` on ``drone`` through its button: the first click only asks "sure?", the second sends."""
    button = page.locator(f"#drones li[data-id='{drone}'] button[data-action='{action}']")
    told = len(served.gateway.commands)
    button.click()
    assert button.get_attribute("data-armed") == "true" and f"sure? {action} {drone}" in button.inner_text()
    page.wait_for_timeout(300)
    assert len(served.gateway.commands) == told, f"one click sent {action} to {drone}"
    button.click()  # enabled again after a moment: a double click is not a confirmation
    page.wait_for_function("([d, a]) => !document.querySelector(`#drones li[data-id='${d}'] "
                           "button[data-action='${a}']`).dataset.armed", arg=[drone, action])


def test_the_operator_pauses_resumes_recalls_and_lands_through_the_page(browser: Any, served: Served,
                                                                        screenshots: Path) -> None:
    """Issue 27, item 4 in the page: the fleet bar, each drone's buttons (recall and land asked twice), what
    the drones answered or a 504 naming the one that did not, and the commands list."""
    watched = Watched()
    page = open_dashboard(browser, served, watched)
    dispatcher = served.app.state.service.dispatcher
    page.wait_for_selector("#commands[data-loaded='true']", timeout=10_000)
    assert page.locator("#commands li[data-n]").count() == 0
    # Pause, then resume the fleet: the dispatcher stops handing out mail, every drone answers, the bar says so.
    page.click("#fleet-pause")
    page.wait_for_selector("#fleet-state[data-state='paused']", timeout=10_000)
    assert served.gateway.commands == [(None, "pause", "ops")] and served.call(lambda: dispatcher.paused)
    assert page.locator("#fleet-msg").get_attribute("data-kind") == "ok"
    assert "pause: d1, d2, d3 acknowledged" in page.locator("#fleet-msg").inner_text()
    page.wait_for_selector("#commands li[data-n='1'][data-action='pause']", timeout=10_000)
    # Mail given while paused waits, and the operator cancels it from its row.
    mail_id = submit(page, (1, 3, 0), (3, 6, 0), 2).split()[0]
    cancel = f"#mail tr[data-id='{mail_id}'][data-status='queued'] button.cancel"
    page.wait_for_selector(cancel, timeout=10_000)
    assert_kept_through_draws(page, cancel)
    page.click(cancel)
    page.wait_for_selector(f"#mail tr[data-id='{mail_id}'][data-status='cancelled']", timeout=10_000)
    assert httpx.get(f"{served.url}/v1/mail/{mail_id}", headers=auth()).json()["status"] == "cancelled"
    page.screenshot(path=str(screenshots / "paused.png"))
    page.click("#fleet-resume")
    page.wait_for_selector("#fleet-state[data-state='running']", timeout=10_000)
    assert served.gateway.commands[-1] == (None, "resume", "ops") and not served.call(lambda: dispatcher.paused)
    # Recall d1 and land d2, each confirmed: the drones are held and answer, the page shows it in their items.
    land_d2 = page.locator("#drones li[data-id='d2'] button[data-action='land']")
    land_d2.click()  # a slip, a double click as a hand makes one: it only asks (arming another gives it up)
    page.wait_for_timeout(150)
    land_d2.click(force=True)  # not waiting until the button takes clicks again
    page.wait_for_timeout(300)
    assert len(served.gateway.commands) == 2, f"a double click sent {served.gateway.commands[2:]}"
    assert land_d2.get_attribute("data-armed") == "true"
    confirm_command(page, served, "d1", "recall")
    assert "recall: d1 acknowledged" in command_outcome(page, "d1").inner_text()
    confirm_command(page, served, "d2", "land")
    assert "land: d2 acknowledged" in command_outcome(page, "d2").inner_text()
    assert served.gateway.commands[2:] == [("d1", "recall", "ops"), ("d2", "land", "ops")]
    assert served.gateway.commanded == {"d1": "recall", "d2": "land"}
    assert served.call(lambda: set(dispatcher.held)) == {"d1", "d2"}
    page.wait_for_selector("#drones li[data-id='d1'][data-command='recall']", timeout=10_000)
    page.wait_for_selector("#drones li[data-id='d2'][data-command='land']", timeout=10_000)
    # Resume d1 (no question asked): it takes mail again; d2 stays landed.
    page.click("#drones li[data-id='d1'] button[data-action='resume']")
    page.wait_for_selector("#drones li[data-id='d1'][data-command=''] .outcome >> text=resume: d1 acknowledged",
                           timeout=10_000)
    assert served.gateway.commanded == {"d2": "land"} and served.call(lambda: set(dispatcher.held)) == {"d2"}
    # A drone that does not answer: a 504, shown as an error naming it, and recorded with no answer.
    served.call(served.gateway.silent.add, "d3")
    confirm_command(page, served, "d3", "recall")
    outcome = command_outcome(page, "d3")
    assert outcome.get_attribute("data-kind") == "error"
    assert "drone d3 did not answer 'recall'" in outcome.inner_text()
    # The audit trail, newest first, as the service keeps it and as the page lists it.
    trail = httpx.get(served.url + "/v1/fleet/commands", headers=auth()).json()
    assert [(c["action"], c["drone"], c["by"]) for c in trail] == [
        ("recall", "d3", "ops"), ("resume", "d1", "ops"), ("land", "d2", "ops"), ("recall", "d1", "ops"),
        ("resume", None, "ops"), ("pause", None, "ops")]
    assert trail[0]["acks"] == [] and trail[2]["acks"] == [{"drone": "d2", "accepted": True, "reason": ""}]
    page.wait_for_selector("#commands li[data-n='6']", timeout=10_000)
    rows = page.locator("#commands li[data-n]")
    assert [rows.nth(i).get_attribute("data-action") for i in range(rows.count())] == [
        "recall", "resume", "land", "recall", "resume", "pause"]
    assert re.search(r"\d\d:\d\d:\d\d ops recall d3 no answer", rows.nth(0).inner_text())
    assert re.search(r"ops land d2 d2 acknowledged", rows.nth(2).inner_text())
    assert re.search(r"ops pause fleet d1, d2, d3 acknowledged", rows.nth(5).inner_text())
    page.locator("#drones li[data-id='d3']").scroll_into_view_if_needed()
    page.screenshot(path=str(screenshots / "commands.png"), full_page=True)
    # At phone width the controls fit, with no horizontal scroll.
    page.set_viewport_size({"width": 390, "height": 844})
    page.wait_for_timeout(300)
    assert page.evaluate(WIDER_THAN_THE_PAGE) == [], "wider than the phone"
    page.screenshot(path=str(screenshots / "commands-phone.png"), full_page=True)
    watched.check(served.url, frozenset({(504, "/v1/fleet/drones/d3/recall")}))
    page.close()
