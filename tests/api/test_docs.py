"""``/docs`` (Swagger UI) works offline: the service serves every asset it loads.

Against ``drona serve`` in its own process; the rendering in headless Chromium, with every request
that leaves the service refused and recorded.
"""

from __future__ import annotations

import re
from typing import Any

import httpx

from tests.api.conftest import ServiceProcess

#: The assets a page refers to in its HTML.
REFERENCE = re.compile(r'(?:src|href)="([^"]*)"')


def test_the_docs_page_refers_only_to_assets_the_service_serves(service: ServiceProcess) -> None:
    res = httpx.get(service.url + "/docs")
    assert res.status_code == 200 and re.search(r"https?://", res.text) is None, res.text
    refs = REFERENCE.findall(res.text)
    assert len(refs) == 3, refs  # the script, the style sheet and the icon
    for ref in refs:
        assert ref.startswith("/") and not ref.startswith("//"), ref
        asset = httpx.get(service.url + ref)
        assert asset.status_code == 200 and asset.content, (ref, asset.status_code)
    assert httpx.get(service.url + "/redoc").status_code == 404  # Redoc would fetch its logo from a CDN


def test_the_docs_render_with_no_request_leaving_the_service(browser: Any, service: ServiceProcess) -> None:
    page = browser.new_page()
    outside: list[str] = []
    errors: list[str] = []

    def only_the_service(route: Any) -> None:
        url = route.request.url
        if url.startswith((service.url + "/", "data:", "blob:")):
            route.continue_()
        else:
            outside.append(url)
            route.abort()

    page.route("**/*", only_the_service)
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(service.url + "/docs")
    page.wait_for_selector(".opblock-summary-path[data-path='/v1/mail/{mail_id}/cancel']", timeout=15_000)
    assert page.locator(".opblock-summary-method", has_text="POST").count() >= 2
    assert outside == [] and errors == []
    page.close()
