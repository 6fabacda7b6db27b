"""GET /ui/: the review page's files from the package, with its security headers; without a build, a 503 problem
that says how to make one."""

from __future__ import annotations

import re

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from services.api import ui
from services.api.problems import install_problem_handlers

pytestmark = pytest.mark.integration


def test_the_page_and_its_assets_are_served_with_the_pages_headers(sqlite_service):
    c = sqlite_service.client
    redirect = c.get("/ui", follow_redirects=False)
    assert redirect.status_code == 308 and redirect.headers["location"] == "/ui/"
    page = c.get("/ui/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert page.headers["cache-control"] == "no-cache"
    csp = page.headers["content-security-policy"]
    assert "default-src 'self'" in csp and "connect-src 'self'" in csp and "frame-ancestors 'none'" in csp
    assets = re.findall(r'(?:src|href)="\./(assets/[^"]+)"', page.text)
    assert any(a.endswith(".js") for a in assets) and any(a.endswith(".css") for a in assets)
    for a in assets:
        r = c.get(f"/ui/{a}")
        assert r.status_code == 200 and "immutable" in r.headers["cache-control"], a
        assert r.headers["x-content-type-options"] == "nosniff"
    # no CDN, no other origin named anywhere in the page's code
    js = c.get(f"/ui/{next(a for a in assets if a.endswith('.js'))}").text
    assert not re.search(r"https?://(?!www\.w3\.org)[a-z0-9.-]+\.[a-z]{2,}/", js)
    missing = c.get("/ui/no-such-file.js")
    assert missing.status_code == 404 and missing.headers["content-type"] == "application/problem+json"
    assert c.get("/ui/../pyproject.toml").status_code == 404


def test_without_a_build_the_page_is_a_503_problem(tmp_path):
    app = FastAPI()
    install_problem_handlers(app)
    ui.install(app, tmp_path)
    r = TestClient(app).get("/ui/")
    assert r.status_code == 503 and r.json()["code"] == "ui-missing" and "npm run build" in r.json()["detail"]
