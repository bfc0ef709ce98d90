"""The dashboard in headless Chromium (Debian's ``chromium``, driven by Playwright): what the page shows.

Skipped, with the reason printed, when Chromium or Playwright is missing (``apt-get install chromium``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tests.api.conftest import OPERATOR, ServiceProcess

#: Moves d3 to the map's last column, draws, and returns its label's extent and the map's width.
LABEL_IN_LAST_COLUMN = """() => {
  const d = state.drones.get("d3"), saved = d.cell;
  d.cell = [state.ws.size[0] - 1, saved[1], saved[2]];
  draw();
  const box = document.querySelector("#map g.drone[data-id='d3'] text").getBBox();
  d.cell = saved;
  draw();
  return [box.x, box.x + box.width, state.ws.size[0]];
}"""


def test_the_dashboard_shows_the_fleet_and_follows_a_mail(browser: Any, workspace_file: Path,
                                                          tmp_path: Path) -> None:
    service = ServiceProcess(workspace_file, tmp_path / "mail.db", sim_step=0.1)
    try:
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(service.url + "/")
        page.fill("#token", OPERATOR)
        page.click("#token-form button")
        page.wait_for_selector("#conn[data-state='live']", timeout=10_000)
        # the map: grid, obstacles, chargers, and every drone with its battery
        assert page.locator("#map .obstacles").get_attribute("d").count("M") == 11
        assert page.locator("#map rect.charger").count() == 2
        page.wait_for_function("document.querySelectorAll('#map g.drone').length === 3", timeout=10_000)
        assert page.locator("#drones tbody tr").count() == 3
        assert float(page.locator("#map g.drone[data-id='d1']").get_attribute("data-battery")) > 0
        # a drone in the last column keeps its label on the map (drawn by the page's own code)
        left, right, width = page.evaluate(LABEL_IN_LAST_COLUMN)
        assert left >= 0 and right <= width, f"d3's label spans {left:.2f}..{right:.2f} of a map {width} wide"
        # submit a mail through the form
        for name, value in (("px", 1), ("py", 3), ("pz", 0), ("dx", 3), ("dy", 6), ("dz", 0), ("priority", 8)):
            page.fill(f"#mail-form [name='{name}']", str(value))
        page.click("#mail-form button")
        page.wait_for_selector("#form-msg[data-kind='ok']", timeout=10_000)
        mail_id = page.locator("#form-msg").inner_text().split()[0]
        row = page.locator(f"#mail tbody tr[data-id='{mail_id}']")
        assert row.count() == 1
        pickup = f"#map .marker.pickup[data-id='{mail_id}']"
        assert page.locator(pickup).count() == 1
        page.wait_for_selector(f"{pickup}[data-status='picked_up']", timeout=20_000)
        # A planned trajectory, drawn. "attached", not "visible": Playwright calls an element with an
        # empty bounding box hidden, and a straight trajectory's polyline is zero wide or zero high.
        traj = page.wait_for_selector("#map polyline.traj", state="attached", timeout=10_000)
        assert traj is not None and len((traj.get_attribute("points") or "").split()) >= 2
        page.screenshot(path=str(tmp_path / "flying.png"))
        page.wait_for_selector(f"{pickup}[data-status='delivered']", timeout=20_000)
        assert row.get_attribute("data-status") == "delivered"
        assert page.locator(f"#map .marker.dropoff[data-id='{mail_id}']").get_attribute("data-status") == "delivered"
        page.screenshot(path=str(tmp_path / "delivered.png"))
        assert (tmp_path / "delivered.png").stat().st_size > 10_000
        # a bad request shows the service's reason
        page.fill("#mail-form [name='px']", "4")
        page.fill("#mail-form [name='py']", "3")
        page.click("#mail-form button")
        page.wait_for_selector("#form-msg[data-kind='error']", timeout=10_000)
        assert "pickup: cell [4, 3, 0] is on an obstacle" in page.locator("#form-msg").inner_text()
        assert errors == []
        page.close()
    finally:
        assert service.stop() == 0
