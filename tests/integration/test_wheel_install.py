"""The built wheel, not the source tree: `graspgen migrate`, `graspgen serve` and one job from a fresh venv outside the
repository (issue 17: the migrations ship inside the service package; the library finds the service through its entry
point).

The venv gets the wheel without dependencies; the dependencies come from the project's venv through a path line in a
.pth file (a path line adds the directory, it does not run the .pth files there, so the editable install of the
repository is not on the path). Every process runs with its working directory outside the repository.
"""

from __future__ import annotations

import os
import re
import shutil
import site
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from services_conftest import GRIPPER, box_stl, settings_env, start_serve, stop_process

pytestmark = [pytest.mark.integration, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]


def _env(**values: object) -> dict[str, str]:
    env = settings_env(**values)
    env.pop("PYTHONPATH", None)
    return env


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("wheel")
    assert not work.resolve().is_relative_to(ROOT)
    src = work / "src"  # a copy of what the wheel is built from, so the build writes nothing into the repository
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    for name in ("graspgen", "services", "migrations"):  # what the Dockerfile copies (services/migrations links there)
        shutil.copytree(ROOT / name, src / name, ignore=ignore, symlinks=True)
    dist = work / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--disable-pip-version-check", "-w", str(dist), "."],
        cwd=src,
        check=True,
        timeout=600,
    )
    (whl,) = dist.glob("graspgen-*.whl")
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=work, check=True, timeout=120)
    (purelib,) = (venv / "lib").glob("python3*/site-packages")
    (purelib / "project-deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q", "--no-deps"]
        + ["--disable-pip-version-check", str(whl)],
        cwd=work,
        check=True,
        timeout=300,
    )
    _seed_numba_cache(purelib / "graspgen")
    return venv


def _seed_numba_cache(installed: Path) -> None:
    """The repository's compiled kernels beside the wheel's sources, as the Dockerfile's `graspgen warmup` provides them
    in the image: numba keys its cache on the source file's mtime and size, so each installed file gets its repository
    twin's mtime (a file that differs recompiles). Without this the first job compiles every kernel (8 min on a busy
    2-core host)."""
    cache = ROOT / "graspgen" / "__pycache__"
    if not cache.is_dir():
        return
    (installed / "__pycache__").mkdir(exist_ok=True)
    for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
        shutil.copy2(f, installed / "__pycache__" / f.name)
    for src in (ROOT / "graspgen").rglob("*.py"):
        twin = installed / src.relative_to(ROOT / "graspgen")
        if twin.is_file():
            st = src.stat()
            os.utime(twin, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_the_wheel_is_the_library_and_the_service(wheel_venv, tmp_path):
    where = subprocess.run(
        [
            str(wheel_venv / "bin" / "python"),
            "-c",
            "import graspgen, importlib.util as u; print(graspgen.__file__); "
            "print(u.find_spec('services.migrations.env').origin)",
        ],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    lib, env_py = where.stdout.split()
    assert Path(lib).is_relative_to(wheel_venv) and Path(env_py).is_relative_to(wheel_venv)
    assert (Path(env_py).parent / "versions" / "0001_initial_schema.py").is_file()


def test_migrate_serve_and_one_job_from_the_wheel(wheel_venv, tmp_path):
    graspgen = str(wheel_venv / "bin" / "graspgen")
    var = tmp_path / "var"
    env = _env(storage_dir=var)
    migrate = subprocess.run([graspgen, "migrate"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert migrate.returncode == 0, migrate.stderr
    assert "is at head" in migrate.stdout and (var / "graspgen.sqlite3").is_file()

    proc, url = start_serve(env, tmp_path / "serve.log", graspgen=graspgen, cwd=tmp_path, timeout=300)
    try:
        token = (var / "admin-token").read_text().strip()
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=600) as c:
            up = c.post("/v1/objects", files={"file": ("box.stl", box_stl())}, data={"name": "box", "units": "mm"})
            assert up.status_code == 201, up.text
            assert c.post("/v1/grippers", json=GRIPPER).status_code == 201
            job = c.post(
                "/v1/jobs", json={"object": "box", "gripper": "pgn-80", "params": {"points": 800, "k1": 4, "k2": 2}}
            )
            assert job.status_code == 202, job.text
            end = time.monotonic() + 900  # the wheel's kernels are new to numba's cache: the first job compiles them
            while (body := c.get(f"/v1/jobs/{job.json()['id']}").json())["state"] in ("queued", "running"):
                assert time.monotonic() < end, body
                time.sleep(0.5)
            assert body["state"] == "succeeded", body
            gs = c.get(f"/v1/grasp-sets/{body['grasp_set']}").json()
            assert gs["format"] == "graspgen.grasp_set/1"
            # the review page ships in the wheel: the page, its assets, and (with a browser here) the set in 3D
            page = c.get("/ui/")
            assert page.status_code == 200 and "text/html" in page.headers["content-type"], page.text[:300]
            for asset in re.findall(r'(?:src|href)="\./(assets/[^"]+)"', page.text):
                assert c.get(f"/ui/{asset}").status_code == 200, asset
            _review_page_draws(url, token, body["grasp_set"])
    finally:
        stop_process(proc)
    assert os.path.exists(var / "graspgen.sqlite3")


def _review_page_draws(url: str, token: str, set_id: int) -> None:
    """The wheel's /ui/ in Chromium draws the set (skipped, as the browser tests are, without Chromium)."""
    from tests.ui.browser import drawn_share, launch, missing

    if missing():
        return
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = launch(p)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"{url}/ui/#/set/{set_id}")
            page.get_by_label("Access token").fill(token)
            page.get_by_role("button", name="Use token").click()
            page.locator(".viewer[data-state=complete]").wait_for(timeout=120_000)
            assert drawn_share(page.locator(".viewer canvas").screenshot()) > 0.02
            assert errors == []
        finally:
            browser.close()
