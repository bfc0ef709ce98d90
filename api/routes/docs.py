"""The API's docs at ``/docs`` (Swagger UI), on assets served here: no CDN, so they work offline.

The assets are the ones the ``fastapi-offline`` package ships (Swagger UI 5, which reads the
OpenAPI 3.1 document FastAPI writes); :func:`api.main.create_app` mounts them at :data:`ASSETS_URL`.
There is no ``/redoc``: Redoc 2 loads its logo from its makers' CDN whatever it is told.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

ASSETS_URL = "/docs-assets"
ASSETS_DIR = Path(str(importlib.resources.files("fastapi_offline") / "static"))
router = APIRouter(include_in_schema=False)


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    root = str(request.scope.get("root_path", "")).rstrip("/")  # the prefix a proxy serves the app under
    return get_swagger_ui_html(
        openapi_url=f"{root}{request.app.openapi_url}", title=f"{request.app.title} - Swagger UI",
        swagger_js_url=f"{root}{ASSETS_URL}/swagger-ui-bundle.js", swagger_css_url=f"{root}{ASSETS_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}{ASSETS_URL}/favicon.png", oauth2_redirect_url=None,
        swagger_ui_parameters={"validatorUrl": None})  # no badge fetched from the online validator
