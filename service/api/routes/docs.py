"""GET /docs: the OpenAPI page, from the Swagger UI files that ship in the package.

FastAPI's own page loads Swagger UI from a CDN and stays blank on a machine without internet (robots and
plants often have none), so the app switches it off and this route serves the same page with the script,
stylesheet and icon of ``static/vendor/swagger-ui/`` (version and licence in the README there).

ReDoc (``/redoc``) is not served: it is a second, read-only rendering of the same ``/openapi.json``; offline
it would need another megabyte of vendored script, and its page template also loads web fonts from Google.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

router = APIRouter(include_in_schema=False)

SWAGGER_UI_FILES = "vendor/swagger-ui"  # under the app's static mount
# The default validator shows a badge fetched from validator.swagger.io: an outside request, and useless
# offline. None switches it off.
SWAGGER_UI_PARAMETERS = {"validatorUrl": None}


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    app = request.app
    root = request.scope.get("root_path", "").rstrip("/")  # behind a proxy that strips a prefix

    def asset(name: str) -> str:
        return root + app.url_path_for("static", path=f"{SWAGGER_UI_FILES}/{name}")

    return get_swagger_ui_html(
        openapi_url=root + app.openapi_url,
        title=f"{app.title}: API docs",
        swagger_js_url=asset("swagger-ui-bundle.js"),
        swagger_css_url=asset("swagger-ui.css"),
        swagger_favicon_url=asset("favicon-32x32.png"),
        swagger_ui_parameters=SWAGGER_UI_PARAMETERS,
    )
