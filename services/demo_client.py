"""A scripted client for a running service: upload a part, register a gripper, run a job, read the result.

    graspgen serve &                                     # writes the admin token to var/graspgen/admin-token
    python -m services.demo_client --token ggt_... [--url http://127.0.0.1:8000] [--part PATH --units mm]

Without --part it uploads a 40 x 30 x 20 mm box made with trimesh. Exit status 0 when the job succeeded.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import httpx

GRIPPER = {
    "name": "demo-pgn-80",
    "stroke": 0.08,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "palm_depth": 0.02,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
}


def _check(r: httpx.Response) -> dict:
    if r.status_code >= 400:
        problem = r.json() if r.headers.get("content-type", "").endswith("json") else {"detail": r.text}
        raise SystemExit(f"demo: {r.request.method} {r.request.url.path}: {r.status_code} {problem.get('detail')}")
    return r.json()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=os.environ.get("GRASPGEN_TOKEN"), help="bearer token (or GRASPGEN_TOKEN)")
    ap.add_argument("--part", type=Path, help="mesh file to upload (default: a generated box)")
    ap.add_argument("--units", default="mm")
    ap.add_argument("--name", default="demo-box")
    ap.add_argument("--points", type=int, default=2000)
    args = ap.parse_args(argv)
    if not args.token:
        ap.error("--token is required (graspgen serve prints one on first start)")
    if args.part:
        data, filename = args.part.read_bytes(), args.part.name
    else:
        import trimesh

        data, filename = trimesh.creation.box(extents=(40.0, 30.0, 20.0)).export(file_type="stl"), "box.stl"
    with httpx.Client(base_url=args.url, headers={"Authorization": f"Bearer {args.token}"}, timeout=60) as c:
        obj = _check(
            c.post("/v1/objects", files={"file": (filename, data)}, data={"name": args.name, "units": args.units})
        )
        print(f"object  {obj['name']} v{obj['version']}  extents {obj['extents']} m  sha256 {obj['sha256'][:12]}")
        grip = _check(c.post("/v1/grippers", json=GRIPPER))
        print(f"gripper {grip['name']} v{grip['version']}")
        job = _check(
            c.post("/v1/jobs", json={"object": obj["name"], "gripper": grip["name"], "params": {"points": args.points}})
        )
        print(f"job     {job['id']} queued")
        while job["state"] not in ("succeeded", "failed", "cancelled"):
            time.sleep(float(job.get("retry_after", 0.5)))
            job = _check(c.get(f"/v1/jobs/{job['id']}"))
            print(f"        {job['state']:<9} {job['stage'] or '':<10} {job['progress']:.0%}", flush=True)
        if job["state"] != "succeeded":
            print(f"demo: job {job['state']}: {(job.get('error') or {}).get('detail')}", file=sys.stderr)
            return 1
        export = _check(c.get(f"/v1/grasp-sets/{job['grasp_set']}"))
        stats = export["stats"]
        print(
            f"grasps  {len(export['grasps'])} from {stats['candidates']} candidates "
            f"(grasp set {job['grasp_set']}, {args.url}/v1/grasp-sets/{job['grasp_set']})"
        )
        for g in export["grasps"][:3]:
            print(
                f"        width {g['width'] * 1000:.1f} mm  margin {g['friction_margin_deg']:.1f} deg  "
                f"free rolls {len(g['free_rolls_deg'])}"
            )
        cat = _check(c.get(f"/v1/catalogue?gripper={grip['name']}"))
        print(f"catalogue for {grip['name']}: {[i['object'] + ' v' + str(i['version']) for i in cat['items']]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
