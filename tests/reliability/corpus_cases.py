"""The bad-input corpus as pytest parameters: corpus/index.json plus every file of ../shared/meshes/bad/.

The CLI tests (test_bad_input_cli.py) and the API tests (test_bad_input_api.py) both iterate `corpus_params()`,
so each entry is one test id in each file and the two interfaces are held to the same list.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

CORPUS = Path(__file__).resolve().parent / "corpus"
SHARED_BAD = Path(__file__).resolve().parents[2].parent / "shared" / "meshes" / "bad"
GOOD_MESH = CORPUS / "meshes" / "good_box_mm.stl"
GOOD_GRIPPER = CORPUS / "grippers" / "good.json"


def known_pair(service, prefix: str) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """An object (GOOD_MESH) and a gripper registered on `service` under new names: {"object": ..., "gripper": ...}."""
    from services_conftest import slug

    names = {"object": slug(f"{prefix}-part"), "gripper": slug(f"{prefix}-grip")}
    assert service.upload(names["object"], GOOD_MESH.read_bytes()).status_code == 201
    assert service.gripper(names["gripper"]).status_code == 201
    return names


#: what ../shared/meshes/MANIFEST.md says each file of bad/ is (all in millimetres); a file not listed here must be
#: rejected or warned about, whatever it is
SHARED_BAD_EXPECT: dict[str, dict[str, Any]] = {
    "empty.stl": {"expect": "reject", "code": "invalid-mesh", "says": ["empty"]},
    "truncated_angle_block.stl": {"expect": "reject", "code": "invalid-mesh", "says": ["truncated", "704 triangles"]},
    "idler_riser_binary_stl.obj": {"expect": "reject", "code": "invalid-mesh", "says": ["binary stl", "rename"]},
    "open_surface_featuretype.stl": {"expect": "warn", "code": "", "says": ["not watertight"]},
}


def load_cases() -> list[dict[str, Any]]:
    cases = []
    for case in json.loads((CORPUS / "index.json").read_text()):
        case = dict(case)
        case["path"] = CORPUS / case["file"]
        if case["kind"] == "params":
            case["params"] = json.loads(case["path"].read_text())
        cases.append(case)
    return cases


def shared_bad_cases() -> list[dict[str, Any]]:
    cases = []
    for path in sorted(p for p in SHARED_BAD.iterdir() if p.is_file()):
        expect = SHARED_BAD_EXPECT.get(path.name, {"expect": "reject-or-warn", "code": "invalid-mesh", "says": []})
        cases.append(
            {"id": f"shared-bad-{path.name}", "kind": "mesh", "file": path.name, "path": path, "units": "mm", **expect}
        )
    return cases


def corpus_params(*, slow_warn: bool = False) -> list[Any]:
    """pytest.param per entry, id = the entry's id; `slow_warn` marks accepted-with-warning meshes slow (the CLI
    runs the whole pipeline on them)."""
    out = []
    for case in load_cases():
        marks = [pytest.mark.slow] if slow_warn and case["expect"] == "warn" else []
        out.append(pytest.param(case, id=case["id"], marks=marks))
    if SHARED_BAD.is_dir():
        for case in shared_bad_cases():
            marks = [pytest.mark.slow] if slow_warn and case["expect"] != "reject" else []
            out.append(pytest.param(case, id=case["id"], marks=marks))
    else:
        reason = f"shared bad meshes not found at {SHARED_BAD} (expected ../shared/meshes/bad beside the repo)"
        out.append(pytest.param(None, id="shared-bad", marks=pytest.mark.skip(reason=reason)))
    return out


def says(case: dict[str, Any], api: bool) -> list[str]:
    return case.get("api_says", case["says"]) if api else case["says"]


def code(case: dict[str, Any]) -> str:
    return case.get("api_code", case["code"])
