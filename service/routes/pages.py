"""Browser pages served from files packaged with the service (``service/static``), nothing from a CDN.

* ``GET /viewer``: the 3-D viewer (three.js, vendored): a phantom's organs, its
  sites, a trace from the page and every path coloured by its gain, with the
  selected sensor's power-delay profile.
* ``GET /docs``: Swagger UI (swagger-ui-dist, vendored) over ``/openapi.json``.
* ``/static/...``: the files themselves; versions in ``static/vendor/README.md``.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"
SWAGGER = "/static/vendor/swagger-ui"

router = APIRouter(include_in_schema=False)


@router.get("/viewer")
async def viewer() -> FileResponse:
    return FileResponse(STATIC_DIR / "viewer" / "index.html", media_type="text/html")


@router.get("/docs")
async def swagger_ui() -> HTMLResponse:
    return get_swagger_ui_html(
        openapi_url="/openapi.json",
        title="CapsuleRT API",
        swagger_js_url=f"{SWAGGER}/swagger-ui-bundle.js",
        swagger_css_url=f"{SWAGGER}/swagger-ui.css",
        swagger_favicon_url=f"{SWAGGER}/favicon-32x32.png",
        oauth2_redirect_url="/docs/oauth2-redirect",
        # no badge from the public validator service: the page talks to this server only
        swagger_ui_parameters={"validatorUrl": None},
    )


@router.get("/docs/oauth2-redirect")
async def swagger_ui_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


def install(app: FastAPI) -> None:
    """Add the pages and the static files to an app (created with ``docs_url=None, redoc_url=None``)."""
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
