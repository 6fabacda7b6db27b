"""How fast the review page loads a grasp set: 64 grasps and 100,000 candidates, `graspgen serve` on localhost,
Debian's Chromium (headless, software WebGL) driven by Playwright.

    .venv/bin/python bench/bench_ui.py [--candidates 100000] [--grasps 64] [--runs 5]

The set is made here, not computed (a job with 100,000 candidates takes minutes): a 60 x 40 x 30 mm box part
uploaded through the API, candidates on its +-X faces written with graspgen's own NPZ writer (export.npz_bytes), 64 of
them exported as grasps with the contract's grasp frames, stored as the worker stores a set (storage blobs, a
grasp-set row, the catalogue refreshed). Each run opens a new tab, enters the token and reads the page's own
performance measures (set page start -> ...): `export` (the export JSON parsed), `drawn` (part and grippers on
screen), `candidates` (the candidate cloud, a view of at most 50,000 rows, fetched, coloured and on screen; the page
draws it in the first frame when it is in by then), `complete` (`.viewer[data-state=complete]`: everything above and
the side pane's header, history and job, seen by a mutation observer). `click` is from just before Playwright clicks
"Use token" to complete, on the page's clock (Playwright's own wait polls every 100-500 ms, too coarse for this).
Prints a table and the machine's load average (the figures move with it); they go to docs/benchmarks.md ("Review
page").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import secrets
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.ui.browser import launch, missing  # noqa: E402

GRIPPER = {
    "name": "pgn-80",
    "stroke": 0.08,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "palm_depth": 0.02,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
    "grip_force": 20.0,
}
EXTENTS_MM = (60.0, 40.0, 30.0)
CLOUD_LIMIT = 50_000  # ui/src/shared.js CLOUD_LIMIT: the most candidates the page draws


def synthetic_set(n: int, m: int, rolls: int = 16, seed: int = 0) -> tuple[dict[str, np.ndarray], list[dict]]:
    """Candidate arrays (CONTRACT.md, "Candidate export") of `n` pairs across the box's X faces, and `m` of them as
    exported grasps (grasp_set/1 entries)."""
    from graspgen.transforms import grasp_frames

    rng = np.random.default_rng(seed)
    half = np.array(EXTENTS_MM) / 2000.0
    yz = rng.uniform(-1, 1, size=(n, 2)) * half[1:] * 0.9
    c0 = np.column_stack([np.full(n, -half[0]), yz])
    c1 = np.column_stack([np.full(n, half[0]), yz])
    contacts = np.stack([c0, c1], axis=1)
    normals = np.broadcast_to(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), (n, 2, 3)).copy()
    midpoints = contacts.mean(axis=1)
    axes = np.broadcast_to(np.array([1.0, 0, 0]), (n, 3)).copy()
    free = rng.random((n, rolls)) > 0.3
    angles = np.arange(rolls) * 2 * np.pi / rolls
    margin = rng.uniform(2, 18, size=n)
    hold = rng.uniform(1, 6, size=n)
    labels = np.column_stack([rng.integers(0, 16, n), rng.integers(0, 4, n)]).astype(np.int32)
    medoids = np.sort(rng.choice(n, size=m, replace=False)).astype(np.int64)
    arrays = {
        "contacts": contacts,
        "normals": normals,
        "midpoints": midpoints,
        "axes": axes,
        "free_rolls": free,
        "roll_angles_rad": angles,
        "friction_margin_deg": margin,
        "labels": labels,
        "medoids": medoids,
        "hold_margin": hold,
    }
    grasps = []
    for i in medoids:
        ks = np.flatnonzero(free[i]) if free[i].any() else np.array([0])
        k = int(ks[len(ks) // 2])
        pose = grasp_frames(midpoints[i], axes[i], angles[k : k + 1])[0]
        grasps.append(
            {
                "pose": pose.tolist(),
                "width": float(2 * half[0]),
                "contacts": contacts[i].tolist(),
                "normals": normals[i].tolist(),
                "friction_margin_deg": float(margin[i]),
                "free_rolls_deg": [float(np.degrees(a)) for a in angles[free[i]]],
                "cluster": [int(labels[i, 0]), int(labels[i, 1])],
                "cluster_size": int(n // m),
                "roll_deg": float(np.degrees(angles[k])),
                "candidate": int(i),
                "hold_margin": float(hold[i]),
            }
        )
    return arrays, grasps


def seed(url: str, token: str, settings, n: int, m: int) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    """The part and gripper through the API, the set written as the worker writes one; returns its id."""
    import trimesh
    from sqlalchemy import select

    from graspgen.export import npz_bytes
    from services.common import catalogue
    from services.common.db import Database
    from services.common.jobs import params_key
    from services.common.models import GraspSet, GripperVersion, ObjectVersion
    from services.common.storage import make_storage

    stl = trimesh.creation.box(extents=EXTENTS_MM).export(file_type="stl")
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as c:
        assert c.post(
            "/v1/objects", files={"file": ("box.stl", stl)}, data={"name": "bench-box", "units": "mm"}
        ).is_success
        assert c.post("/v1/grippers", json=GRIPPER).is_success
    arrays, grasps = synthetic_set(n, m)
    params = {"points": 20000, "friction": 0.5, "safety_factor": 1.5, "rolls": 16, "k1": 16, "k2": 4, "seed": 0}
    export = {
        "format": "graspgen.grasp_set/1",
        "units": "m",
        "object": {"name": "bench-box", "version": 1, "sha256": hashlib.sha256(stl).hexdigest(), "source_units": "mm"},
        "gripper": GRIPPER,
        "params": params,
        "stats": {
            "points": 20000,
            "pairs_total": 199990000,
            "rejected": {"stroke": 150000000, "outside": 40000000, "friction": 9800000, "collision": 90000},
            "candidates": n,
            "timings_s": {"sample": 0.4, "pairs": 1.2, "collision": 3.1, "cluster": 0.8, "total": 5.5},
            "coverage": {
                "candidates": n,
                "selected": m,
                "levels": [{"radius": 0.01, "angle_deg": 30.0, "share": 0.97}],
            },
        },
        "grasps": grasps,
    }
    storage = make_storage(settings)
    db = Database(settings)
    try:
        blob = storage.put_bytes(json.dumps(export).encode())
        cands = storage.put_bytes(npz_bytes(arrays))
        with db.session() as s:
            ov = s.execute(select(ObjectVersion)).scalars().one()
            gv = s.execute(select(GripperVersion)).scalars().one()
            gs = GraspSet(
                object_id=ov.object_id,
                gripper_id=gv.gripper_id,
                version=1,
                object_version_id=ov.id,
                gripper_version_id=gv.id,
                params=params,
                params_key=params_key(params, None),
                job_id=uuid.uuid4(),
                stats=export["stats"],
                grasp_count=m,
                export_key=blob.key,
                export_sha256=blob.sha256,
                export_size=blob.size,
                candidates_key=cands.key,
            )
            s.add(gs)
            s.flush()
            catalogue.refresh(s, object_id=ov.object_id, gripper_id=gv.gripper_id)
            s.commit()
            return gs.id, cands.size
    finally:
        db.dispose()


def server_times(url: str, token: str, set_id: int, n: int = 10) -> tuple[dict[str, float], float, int]:
    """Median ms of the page's requests from a plain HTTP client (what the server and loopback take), the first
    request of the candidate view (ms: the view made, not yet cached) and the view's size in bytes."""
    paths = {
        "export": f"/v1/grasp-sets/{set_id}",
        "object file": "/v1/objects/bench-box/versions/1/file",
        "candidate NPZ": f"/v1/grasp-sets/{set_id}/candidates",
        # the page's request (ui/src/shared.js, loadCandidates); made once, then from the API's cache
        "candidate view": f"/v1/grasp-sets/{set_id}/candidates?arrays=midpoints,friction_margin_deg,hold_margin"
        f"&max_rows={CLOUD_LIMIT}",
        "set summary": "/v1/grasp-sets?object=bench-box&gripper=pgn-80&limit=200",
        "catalogue": "/v1/catalogue/bench-box/pgn-80",
        "history": "/v1/catalogue/bench-box/pgn-80/history?limit=5",
        "job (404)": f"/v1/jobs/{uuid.uuid4()}",
    }
    out = {}
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as c:
        for label, path in paths.items():
            times = []
            for _ in range(n):
                t = time.perf_counter()
                r = c.get(path)
                times.append((time.perf_counter() - t) * 1000)
                assert r.status_code == (404 if "404" in label else 200)
                if label == "candidate view" and len(times) == 1:
                    view_first, view_size = times[0], len(r.content)
            out[label] = statistics.median(times)
    return out, view_first, view_size


#: run in the page before the click: the click's time, and when the viewer's data-state turns `complete` (a mutation
#: observer's callback runs right after the change), both on the page's clock
WATCH = """() => {
  window.__bench = {click: performance.now()};
  new MutationObserver(() => {
    if (!window.__bench.complete && document.querySelector('.viewer[data-state=complete]')) {
      window.__bench.complete = performance.now();
    }
  }).observe(document.body, {subtree: true, childList: true, attributes: true, attributeFilter: ['data-state']});
}"""


def run_page(browser, url: str, token: str, set_id: int) -> dict[str, float]:  # type: ignore[no-untyped-def]
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    # the made-up set's job id names no job: the page's 404 for it is expected (Chromium logs every 4xx)
    page.on(
        "console",
        lambda msg: (
            errors.append(msg.text) if msg.type == "error" and "/v1/jobs/" not in msg.location.get("url", "") else None
        ),
    )
    page.goto(f"{url}/ui/#/set/{set_id}")
    page.get_by_label("Access token").fill(token)
    page.evaluate(WATCH)
    page.get_by_role("button", name="Use token").click()
    page.locator(".viewer[data-state=complete]").wait_for(timeout=120_000)
    watched = page.evaluate("window.__bench")
    measures = page.evaluate(
        "Object.fromEntries(performance.getEntriesByType('measure').map(m => [m.name, m.duration]))"
    )
    marks = page.evaluate("Object.fromEntries(performance.getEntriesByType('mark').map(m => [m.name, m.startTime]))")
    drawn = int(page.locator(".viewer").get_attribute("data-drawn-candidates") or 0)
    if "-v" in sys.argv:
        print({k: round(v - marks["gg:set:start"]) for k, v in sorted(marks.items(), key=lambda kv: kv[1])})
    page.close()
    assert not errors, errors
    start = marks["gg:set:start"]
    export = next(v for k, v in marks.items() if k.endswith(":export")) - start
    return {
        "export": export,
        "drawn": measures["gg:set:drawn"],
        "candidates": measures["gg:set:candidates"],
        "complete": watched["complete"] - start,
        "click": watched["complete"] - watched["click"],
        "n": drawn,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", type=int, default=100_000)
    ap.add_argument("--grasps", type=int, default=64)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("-v", action="store_true", help="print every mark of each run")
    args = ap.parse_args()
    reason = missing()
    if reason:
        sys.exit(f"bench_ui: {reason}")
    load = os.getloadavg()
    from playwright.sync_api import sync_playwright

    from services.common.migrate import upgrade
    from services.common.settings import Settings
    from services.common.tokens import hash_token
    from tests.services_conftest import free_port, settings_env, stop_process, wait_http

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        token = "ggt_bench_" + secrets.token_urlsafe(16)
        doc = {"tokens": [{"name": "bench", "sha256": hash_token(token), "scopes": ["write"]}]}
        (root / "tokens.json").write_text(json.dumps(doc))
        settings = Settings(storage_dir=root / "var", tokens_file=root / "tokens.json")
        upgrade(settings)
        port = free_port()
        env = settings_env(storage_dir=root / "var", tokens_file=root / "tokens.json", log_level="warning")
        with open(root / "serve.log", "wb") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "services.cli", "serve", "--port", str(port)], env=env, stdout=log, stderr=log
            )
        url = f"http://127.0.0.1:{port}"
        try:
            wait_http(url + "/healthz", timeout=120)
            set_id, npz_size = seed(url, token, settings, args.candidates, args.grasps)
            served, view_first, view_size = server_times(url, token, set_id)
            rows = []
            with sync_playwright() as p:
                browser = launch(p)
                try:
                    run_page(browser, url, token, set_id)  # warm-up: the server's caches, Chromium's code cache
                    rows = [run_page(browser, url, token, set_id) for _ in range(args.runs)]
                finally:
                    browser.close()
        finally:
            stop_process(proc)
    print(f"review page: set of {args.grasps} grasps, {args.candidates:,} candidates (NPZ {npz_size / 1e6:.1f} MB), ")
    print(f"{rows[0]['n']:,} of them drawn (the page's view of them: {view_size / 1e6:.1f} MB); Chromium headless, ")
    after = os.getloadavg()[0]
    print(f"SwiftShader; {args.runs} runs after one warm-up; load average {load[0]:.1f} before, {after:.1f} after\n")
    print(f"| {'from the set page start to':<42} | median ms | min ms | max ms |")
    print(f"|{'-' * 44}|-----------|--------|--------|")
    labels = {
        "export": "export JSON parsed",
        "drawn": f"part and {args.grasps} grippers on screen",
        "candidates": "candidate cloud on screen",
        "complete": "page complete (data-state=complete)",
        "click": "'Use token' click -> complete",
    }
    for key, label in labels.items():
        v = [r[key] for r in rows]
        print(f"| {label:<42} | {statistics.median(v):9.0f} | {min(v):6.0f} | {max(v):6.0f} |")
    print(
        "\nthe same requests from httpx (server and loopback alone), median of 10: "
        + ", ".join(f"{k} {v:.0f} ms" for k, v in served.items())
        + f"; the view's first request (made, then cached) {view_first:.0f} ms"
    )


if __name__ == "__main__":
    main()
