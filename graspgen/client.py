"""A Python client of the graspgen HTTP API (CONTRACT.md, docs/API.md), on httpx.

```python
from graspgen.client import Client

with Client("http://graspgen:8000", token) as gg:
    gg.upload_object("ring-screw.stl", name="ring-screw", units="mm")
    gg.create_gripper(json.load(open("pgn-80.json")))
    gg.upload_gripper("examples/pgn-80-vgroove.json")  # a spec with geometry, with its mesh files
    gg.upload_gripper("examples/cup-30.json")  # a suction cup (CONTRACT.md "Suction cups")
    job = gg.wait(gg.submit_job("ring-screw", "pgn-80", params={"points": 10000}))
    gg.release(job["grasp_set"])
    best = gg.pick(T_world_object, object="ring-screw", gripper="pgn-80",
                   approach={"direction": [0, 0, -1], "max_angle_deg": 30},
                   planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}])["grasps"][0]
```

Every error response becomes a `ProblemError` carrying the RFC 9457 problem document. Reads and job submissions
(which carry an Idempotency-Key) are retried on 429 and 503, after the `Retry-After` the server sends. `import
graspgen` does not import this module, so the library does not need httpx.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

__all__ = ["Client", "CatalogueEntry", "ClientError", "ProblemError", "JobFailedError"]

TERMINAL = ("succeeded", "failed", "cancelled")
#: statuses after which a safe request is sent again, after Retry-After
RETRY_STATUSES = (429, 503)


class ClientError(Exception):
    """Base of the client's errors."""


class ProblemError(ClientError):
    """An error response: `status`, and the problem+json document as `problem` (`code`, `detail`, `field`...)."""

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        self.code: str = str(problem.get("code", "error"))
        self.detail: str = str(problem.get("detail", ""))
        super().__init__(f"{status} {self.code}: {self.detail}")


class JobFailedError(ClientError):
    """`wait` on a job that ended `failed` or `cancelled`; `job` is its last state (with `error`)."""

    def __init__(self, job: dict[str, Any]) -> None:
        self.job = job
        error = job.get("error") or {}
        super().__init__(f"job {job.get('id')} {job.get('state')}: {error.get('detail', '')}".rstrip(": "))


@dataclass(frozen=True)
class CatalogueEntry:
    """What the catalogue serves for an object and gripper: the export and the response's headers."""

    grasp_set: int
    released: bool
    stale: bool
    etag: str
    export: dict[str, Any]
    #: True when the server answered 304 and the export came from the local cache
    from_cache: bool


def _geometry_files(spec: Mapping[str, Any]) -> list[str]:
    """The distinct mesh file names a spec's geometry gives (finger, finger_left, body), in that order."""
    geometry = spec.get("geometry")
    if not isinstance(geometry, Mapping):
        return []
    names = [geometry[k] for k in ("finger", "finger_left", "body") if isinstance(geometry.get(k), str)]
    return list(dict.fromkeys(names))


def _jsonable(value: Any) -> Any:
    """numpy arrays and scalars in a request body as plain lists and numbers."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Mapping):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def _retry_after(response: httpx.Response, default: float) -> float:
    try:
        return max(0.0, float(response.headers.get("retry-after", default)))
    except ValueError:  # an HTTP date: not sent by graspgen
        return default


class Client:
    """`Client(base_url, token)`: one connection pool; use it as a context manager or call `close()`.

    `cache_dir`: where the catalogue's ETag cache is kept between runs (default: in memory only).
    `retries`: how often a safe request is re-sent after a 429 / 503 or a dropped connection.
    """

    def __init__(
        self,
        base_url: str,
        token: str | None = None,
        *,
        timeout: float = 30.0,
        retries: int = 3,
        cache_dir: str | os.PathLike[str] | None = None,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"Accept": "application/json, application/problem+json"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(base_url=base_url.rstrip("/"), headers=headers, timeout=timeout, transport=transport)
        self.retries = retries
        self._cache: dict[str, dict[str, Any]] = {}
        self._cache_dir = Path(cache_dir) if cache_dir is not None else None
        if self._cache_dir is not None:
            self._cache_dir.mkdir(parents=True, exist_ok=True)

    # -- plumbing --------------------------------------------------------------------------------------------------
    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _send(self, method: str, url: str, *, safe: bool, ok: tuple[int, ...] = (), **kw: Any) -> httpx.Response:
        for attempt in range(self.retries + 1):
            last = attempt == self.retries
            try:
                r = self._http.request(method, url, **kw)
            except (httpx.ConnectError, httpx.RemoteProtocolError, httpx.ReadError):
                if not safe or last:
                    raise
                time.sleep(min(2.0**attempt * 0.2, 5.0))
                continue
            if r.status_code in RETRY_STATUSES and safe and not last:
                time.sleep(min(_retry_after(r, 1.0), 60.0))
                continue
            if r.status_code >= 400 and r.status_code not in ok:
                raise ProblemError(r.status_code, _problem(r))
            return r
        raise AssertionError("unreachable")

    def _get(self, url: str, **kw: Any) -> dict[str, Any]:
        return _object(self._send("GET", url, safe=True, **kw))

    # -- objects and grippers --------------------------------------------------------------------------------------
    def upload_object(
        self,
        file: str | os.PathLike[str] | bytes,
        *,
        name: str,
        units: str,
        filename: str | None = None,
        format: str | None = None,
        mass_kg: float | None = None,
    ) -> dict[str, Any]:
        """Upload a mesh or point cloud (`units`: mm, cm, m or in). The same bytes again give the existing version."""
        if isinstance(file, bytes):
            data, filename = file, filename or "part.stl"
        else:
            data, filename = Path(file).read_bytes(), filename or Path(file).name
        form: dict[str, Any] = {"name": name, "units": units}
        if format is not None:
            form["format"] = format
        if mass_kg is not None:
            form["mass_kg"] = str(mass_kg)
        # an upload is idempotent (same bytes, same version), so it is safe to send again
        return _object(self._send("POST", "/v1/objects", safe=True, files={"file": (filename, data)}, data=form))

    def object(self, name: str) -> dict[str, Any]:
        return self._get(f"/v1/objects/{name}")

    def create_gripper(
        self,
        spec: Mapping[str, Any] | Any,
        *,
        files: Mapping[str, bytes | str | os.PathLike[str]] | None = None,
        base_dir: str | os.PathLike[str] | None = None,
    ) -> dict[str, Any]:
        """Register a gripper spec of either kind (dict, graspgen.GripperSpec or graspgen.suction.SuctionSpec); an
        identical spec gives the existing version.

        A spec with `geometry` (CONTRACT.md "Gripper geometry from CAD": fingers and body; "Suction cups": the tool's
        body) goes as multipart with the mesh files it names: `files` maps each name to its bytes or a path; else each
        is read relative to `base_dir`. The same spec and files again give the existing version; a changed file gives
        a new one."""
        body = spec.to_dict() if hasattr(spec, "to_dict") else dict(spec)
        names = _geometry_files(body)
        if not names:
            return _object(self._send("POST", "/v1/grippers", safe=True, json=_jsonable(body)))
        if files is not None:  # every file given goes: the server names a missing or an extra one (422)
            given = {n: v if isinstance(v, bytes) else Path(v).read_bytes() for n, v in files.items()}
        elif base_dir is not None:
            given = {n: (Path(base_dir) / n).read_bytes() for n in names}
        else:
            raise ClientError("a spec with geometry needs its mesh files: pass files= or base_dir=")
        parts = [(n, (n.rsplit("/", 1)[-1], data, "application/octet-stream")) for n, data in given.items()]
        form = {"spec": json.dumps(_jsonable(body))}
        # registering is idempotent (the same spec and files give the same version), so it is safe to send again
        return _object(self._send("POST", "/v1/grippers", safe=True, data=form, files=parts))

    def upload_gripper(self, spec_path: str | os.PathLike[str]) -> dict[str, Any]:
        """Register the gripper spec in a JSON file, with the mesh files its geometry names (relative to it)."""
        path = Path(spec_path)
        return self.create_gripper(json.loads(path.read_text(encoding="utf-8")), base_dir=path.parent)

    def gripper_file(self, name: str, version: int, path: str) -> bytes:
        """The bytes of mesh file `path` of gripper `name` version `version`, as uploaded."""
        return self._send("GET", f"/v1/grippers/{name}/versions/{version}/files/{path}", safe=True).content

    def gripper(self, name: str) -> dict[str, Any]:
        return self._get(f"/v1/grippers/{name}")

    # -- jobs ------------------------------------------------------------------------------------------------------
    def submit_job(
        self,
        object: str,
        gripper: str,
        *,
        params: Mapping[str, Any] | None = None,
        object_version: int | None = None,
        gripper_version: int | None = None,
        idempotency_key: str | None = None,
    ) -> dict[str, Any]:
        """Submit a generate job; returns the job (state `queued`). The Idempotency-Key (a new UUID unless given)
        makes the retries this client does, and yours with the same key, return the same job."""
        body: dict[str, Any] = {"object": object, "gripper": gripper}
        if params is not None:
            body["params"] = _jsonable(dict(params))
        if object_version is not None:
            body["object_version"] = object_version
        if gripper_version is not None:
            body["gripper_version"] = gripper_version
        return self.submit(body, idempotency_key=idempotency_key)

    def submit(self, body: Mapping[str, Any], *, idempotency_key: str | None = None) -> dict[str, Any]:
        """Any job body of `POST /v1/jobs` (e.g. `{"kind": "cluster", "grasp_set": 17, "params": {...}}`)."""
        key = idempotency_key or str(uuid.uuid4())
        r = self._send("POST", "/v1/jobs", safe=True, json=_jsonable(dict(body)), headers={"Idempotency-Key": key})
        return _object(r)

    def job(self, job: str | Mapping[str, Any]) -> dict[str, Any]:
        return self._get(f"/v1/jobs/{_job_id(job)}")

    def wait(
        self, job: str | Mapping[str, Any], *, timeout: float = 900.0, raise_on_failure: bool = True
    ) -> dict[str, Any]:
        """Poll a job until it is succeeded, failed or cancelled, sleeping as long as each answer's Retry-After
        says. Returns the final job; a failed or cancelled one raises JobFailedError unless `raise_on_failure` is
        false. TimeoutError after `timeout` seconds."""
        url = f"/v1/jobs/{_job_id(job)}"
        end = time.monotonic() + timeout
        while True:
            r = self._send("GET", url, safe=True)
            body = _object(r)
            if body["state"] in TERMINAL:
                if raise_on_failure and body["state"] != "succeeded":
                    raise JobFailedError(body)
                return body
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"job {body['id']} still {body['state']} after {timeout} s")
            time.sleep(min(_retry_after(r, 1.0), left))

    def cancel(self, job: str | Mapping[str, Any]) -> dict[str, Any]:
        return _object(self._send("POST", f"/v1/jobs/{_job_id(job)}/cancel", safe=True))

    # -- grasp sets and the catalogue ------------------------------------------------------------------------------
    def grasp_set(self, grasp_set: int) -> dict[str, Any]:
        """The grasp_set/1 export of a grasp set (immutable, so cached locally by its ETag)."""
        return self._conditional(f"/v1/grasp-sets/{int(grasp_set)}")[0]

    def candidates(self, grasp_set: int) -> Any:
        """The candidate NPZ of a grasp set, for graspgen.pick without the server: graspgen.Candidates for a
        parallel gripper's set, graspgen.suction.SuctionCandidates for a suction set (one contact per candidate)."""
        import numpy as np

        from .export import load_candidates
        from .suction import load_suction_candidates

        r = self._send("GET", f"/v1/grasp-sets/{int(grasp_set)}/candidates", safe=True)
        with np.load(io.BytesIO(r.content), allow_pickle=False) as z:
            one_contact = "contacts" in z.files and z["contacts"].ndim == 3 and z["contacts"].shape[1] == 1
        return (load_suction_candidates if one_contact else load_candidates)(io.BytesIO(r.content))

    def catalogue(self, object: str, gripper: str, *, version: int | None = None) -> CatalogueEntry:
        """The grasp set robots should use for the pair (released, else newest). The export is kept with its ETag;
        asking again sends If-None-Match, and a 304 reuses the kept copy."""
        url = f"/v1/catalogue/{object}/{gripper}" + (f"?version={int(version)}" if version else "")
        export, headers, cached = self._conditional(url)
        return CatalogueEntry(
            grasp_set=int(headers.get("graspgen-set-id") or _set_id(headers)),
            released=headers.get("graspgen-released") == "true",
            stale=headers.get("graspgen-stale") == "true",
            etag=headers.get("etag", ""),
            export=export,
            from_cache=cached,
        )

    def release(self, grasp_set: int) -> dict[str, Any]:
        """Make the set the released one of its object and gripper pair (scope write)."""
        return _object(self._send("POST", f"/v1/grasp-sets/{int(grasp_set)}/release", safe=True))

    def withdraw(self, grasp_set: int) -> dict[str, Any]:
        """Stop the catalogue serving the set (scope write)."""
        return _object(self._send("POST", f"/v1/grasp-sets/{int(grasp_set)}/withdraw", safe=True))

    # -- pick ------------------------------------------------------------------------------------------------------
    def pick(
        self,
        T_world_object: Any,
        *,
        object: str | None = None,
        gripper: str | None = None,
        grasp_set: int | None = None,
        approach: Mapping[str, Any] | None = None,
        planes: Sequence[Mapping[str, Any]] | None = None,
        pregrasp_distance: float | None = None,
        T_tcp_flange: Any = None,
        limit: int | None = None,
    ) -> dict[str, Any]:
        """`POST /v1/pick`: world-frame grasps for the part at `T_world_object` (4x4, metres; numpy is fine).
        Give `object` and `gripper` (the catalogue's current set) or `grasp_set`. docs/API.md explains the rest."""
        body: dict[str, Any] = {"T_world_object": T_world_object}
        for key, value in (
            ("object", object),
            ("gripper", gripper),
            ("grasp_set", grasp_set),
            ("approach", approach),
            ("planes", planes),
            ("pregrasp_distance", pregrasp_distance),
            ("T_tcp_flange", T_tcp_flange),
            ("limit", limit),
        ):
            if value is not None:
                body[key] = value
        return _object(self._send("POST", "/v1/pick", safe=True, json=_jsonable(body)))

    # -- the ETag cache --------------------------------------------------------------------------------------------
    def _conditional(self, url: str) -> tuple[dict[str, Any], dict[str, str], bool]:
        kept = self._cache.get(url) or self._load(url)
        headers = {"If-None-Match": kept["etag"]} if kept else {}
        r = self._send("GET", url, safe=True, headers=headers)
        if r.status_code == 304 and kept:
            return kept["body"], {**kept["headers"], **{k.lower(): v for k, v in r.headers.items()}}, True
        keep = ("etag", "graspgen-set-id", "graspgen-released", "graspgen-stale", "content-location")
        entry = {
            "etag": r.headers.get("etag", ""),
            "headers": {k: r.headers[k] for k in keep if k in r.headers},
            "body": r.json(),
        }
        if entry["etag"]:
            self._cache[url] = entry
            self._store(url, entry)
        return entry["body"], entry["headers"], False

    def _path(self, url: str) -> Path | None:
        if self._cache_dir is None:
            return None
        base = str(self._http.base_url)
        return self._cache_dir / (hashlib.sha256((base + url).encode()).hexdigest() + ".json")

    def _load(self, url: str) -> dict[str, Any] | None:
        path = self._path(url)
        if path is None or not path.is_file():
            return None
        try:
            entry: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None  # a damaged cache file is only a miss
        self._cache[url] = entry
        return entry

    def _store(self, url: str, entry: dict[str, Any]) -> None:
        path = self._path(url)
        if path is None:
            return
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(entry), encoding="utf-8")
        os.replace(tmp, path)


def _object(r: httpx.Response) -> dict[str, Any]:
    """The response's JSON body, a JSON object for every endpoint the client reads it from."""
    body: dict[str, Any] = r.json()
    return body


def _problem(r: httpx.Response) -> dict[str, Any]:
    try:
        body = r.json()
    except ValueError:
        body = None
    if isinstance(body, dict):
        return body
    return {"status": r.status_code, "code": "error", "detail": r.text[:500]}


def _job_id(job: str | Mapping[str, Any]) -> str:
    return str(job["id"]) if isinstance(job, Mapping) else str(job)


def _set_id(headers: Mapping[str, str]) -> int:
    # older servers name the set only in Content-Location: /v1/grasp-sets/{id}
    return int(str(headers.get("content-location", "0")).rsplit("/", 1)[-1] or 0)
