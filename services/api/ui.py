"""The review page (CONTRACT.md, "Review page"): `GET /ui/` and its assets, served by the API process itself.

The files are the build of `ui/` (Vite; `ui/package-lock.json` pins every front-end dependency), checked in under
services/api/ui/ and shipped in the wheel as package data, so a plant runs it offline with no Node.js and no second
server. The page is a client of `/v1` like any other: it sends the bearer token the user typed (kept in the tab's
memory) with each request. Its Content-Security-Policy allows nothing but this origin, so no request can leave it.
"""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import RedirectResponse
from starlette.responses import Response
from starlette.staticfiles import StaticFiles
from starlette.types import Scope

from .problems import ApiError

__all__ = ["UI_DIR", "install"]

#: the built page (index.html and assets/), inside the package
UI_DIR = Path(__file__).with_name("ui")

#: only this origin, for scripts, styles, data and workers; blob: for images three.js decodes from a GLB
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self'; "
        "worker-src 'self' blob:; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Opener-Policy": "same-origin",
}


class _PageFiles(StaticFiles):
    """Static files with the page's security headers; hashed assets are immutable, index.html is revalidated."""

    def file_response(
        self, full_path: str | os.PathLike[str], stat_result: os.stat_result, scope: Scope, status_code: int = 200
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers.update(SECURITY_HEADERS)
        hashed = Path(full_path).parent.name == "assets"
        response.headers["Cache-Control"] = "public, max-age=31536000, immutable" if hashed else "no-cache"
        return response


def install(app: FastAPI, directory: Path = UI_DIR) -> None:
    """Serve the page at /ui/ (and /ui -> /ui/); without a build, /ui/ is a 503 problem that says how to make one."""

    @app.get("/ui", include_in_schema=False)
    async def ui_redirect() -> RedirectResponse:
        return RedirectResponse("/ui/", status_code=308)

    if (directory / "index.html").is_file():
        app.mount("/ui", _PageFiles(directory=directory, html=True), name="ui")
        return

    @app.get("/ui/{rest:path}", include_in_schema=False)
    async def ui_missing(rest: str) -> Response:
        raise ApiError(503, "ui-missing", f"the review page is not built into {directory}: run `npm run build` in ui/")
