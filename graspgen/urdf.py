"""`graspgen gripper import HAND.urdf --out DIR`: a URDF of a parallel gripper -> a gripper spec with `geometry` and its
meshes (CONTRACT.md "Gripper geometry from CAD"), in metres.

What is imported: a kinematic tree whose only moving joints are two prismatic finger joints (one may be a `mimic` of
the other) along parallel axes, moving the fingers symmetrically in opposite directions. Everything in the subtree of
a finger joint is that finger; every other link is the body. Each link's `collision` geometry is used, its `visual`
geometry when it has none; meshes (STL, OBJ, PLY, OFF, GLB; `package://` and relative paths, `scale`) and the
primitives box, cylinder and sphere. Anything else is refused with the reason: revolute or other moving joints, one
finger or more than two, axes that are not parallel, asymmetric travel, a finger without geometry, a missing mesh.

The frames, at the URDF's zero configuration (each step is in docs/API.md, "Importing a URDF"):
- X, the closing axis: along the finger joints' axis, pointing from the finger that lies further along -X to the other
  one (that one becomes `finger`, the other `finger_left`).
- Z, the approach: from the body's bounding-box centre towards the fingers' (made orthogonal to X), unless `approach`
  gives it (a vector in the URDF's root link frame); Y = Z x X.
- The contact point of each finger (a URDF names none): the pad centre at the finger's innermost face: on the
  finger's vertices that lie innermost along X (within FRAME_TOLERANCE), the centre of their extent along Y and Z.
  Both pads must face each other (their centres may differ by at most PAD_ALIGNMENT along Y and Z).
- The grasp frame's origin: the midpoint of the two contact points (fixed while the fingers move symmetrically).
- stroke: the largest distance between the two contact points over the joint limits; min_width the smallest (>= 0).
- grip_force: the finger joint's `effort` limit (N) when the URDF gives one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .errors import GraspgenError, InvalidGripperError
from .example_grippers import stl_bytes
from .gripper import GripperSpec
from .gripper_geometry import FRAME_TOLERANCE

__all__ = ["import_urdf", "PAD_ALIGNMENT", "AXIS_TOLERANCE_DEG"]

#: metres: how far the two pads' centres may lie apart along Y or Z
PAD_ALIGNMENT = 1.0e-4
#: degrees: how far from parallel the two finger joints' axes may be
AXIS_TOLERANCE_DEG = 1.0
_MOVING = ("revolute", "continuous", "prismatic", "planar", "floating")


@dataclass
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) T_parent_joint
    axis: np.ndarray  # (3,) in the joint frame
    lower: float | None
    upper: float | None
    effort: float | None
    mimic: tuple[str, float, float] | None  # (joint, multiplier, offset)


@dataclass
class _Link:
    name: str
    shapes: list[tuple[np.ndarray, trimesh.Trimesh]] = field(default_factory=list)  # (T_link_shape, mesh)


def import_urdf(
    urdf: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    name: str | None = None,
    friction: float = 0.5,
    pregrasp_clearance: float = 0.02,
    approach: tuple[float, float, float] | None = None,
    packages: dict[str, str | os.PathLike[str]] | None = None,
) -> Path:
    """Write `<name>.json` and its meshes (`<name>-finger.stl`, `<name>-finger-left.stl` when the fingers differ,
    `<name>-body.stl`) into `out_dir`; returns the spec's path. The written spec is loaded and checked before
    anything is moved into `out_dir`; any refusal is an InvalidGripperError and writes nothing.
    `packages` maps a ROS package name to its folder for `package://` paths (default: a folder of that name above
    the URDF, or the URDF's folder)."""
    path = Path(urdf)
    root = _parse(path)
    links, joints = _model(root, path, packages or {})
    spec, files = _gripper(
        root, links, joints, name=name, friction=friction, clearance=pregrasp_clearance, approach=approach
    )
    return _write(spec, files, Path(out_dir))


# -- reading -----------------------------------------------------------------------------------------------------------
def _parse(path: Path) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise InvalidGripperError(f"cannot read {path}: {exc.strerror or exc}") from None
    except ET.ParseError as exc:
        raise InvalidGripperError(f"{path} is not valid XML: {exc}") from None
    if root.tag != "robot":
        raise InvalidGripperError(f"{path} is not a URDF: its root element is <{root.tag}>, not <robot>")
    return root


def _floats(text: str | None, n: int, what: str, default: tuple[float, ...] | None = None) -> np.ndarray:
    if text is None:
        if default is None:
            raise InvalidGripperError(f"{what} is missing")
        return np.array(default, dtype=float)
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        raise InvalidGripperError(f"{what} = {text!r} is not {n} numbers") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise InvalidGripperError(f"{what} = {text!r} is not {n} finite numbers")
    return np.array(values)


def _number(el: ET.Element | None, key: str, what: str) -> float | None:
    """The attribute `key` of `el` as a finite number; None when `el` or the attribute is absent."""
    text = None if el is None else el.get(key)
    return None if text is None else float(_floats(text, 1, what)[0])


def _origin(el: ET.Element | None, what: str) -> np.ndarray:
    T = np.eye(4)
    if el is None:
        return T
    xyz = _floats(el.get("xyz"), 3, f"{what} origin xyz", (0.0, 0.0, 0.0))
    r, p, y = _floats(el.get("rpy"), 3, f"{what} origin rpy", (0.0, 0.0, 0.0))
    # URDF: fixed-axis roll about X, then pitch about Y, then yaw about Z
    T[:3, :3] = _rot(2, y) @ _rot(1, p) @ _rot(0, r)
    T[:3, 3] = xyz
    return T


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _model(root: ET.Element, path: Path, packages: dict[str, Any]) -> tuple[dict[str, _Link], list[_Joint]]:
    links: dict[str, _Link] = {}
    for el in root.findall("link"):
        link = _Link(el.get("name") or "")
        if not link.name or link.name in links:
            raise InvalidGripperError(f"a link has no name or a repeated one ({link.name!r})")
        shapes = el.findall("collision") or el.findall("visual")
        for s in shapes:
            geometry = s.find("geometry")
            if geometry is None or len(geometry) == 0:
                raise InvalidGripperError(f"link {link.name!r} has a {s.tag} without geometry")
            mesh = _shape(geometry[0], link.name, path, packages)
            link.shapes.append((_origin(s.find("origin"), f"link {link.name!r} {s.tag}"), mesh))
        links[link.name] = link
    joints = []
    for el in root.findall("joint"):
        jname, jtype = el.get("name") or "", el.get("type") or ""
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None or parent.get("link") not in links or child.get("link") not in links:
            raise InvalidGripperError(f"joint {jname!r} does not connect two links of the URDF")
        limit, mimic = el.find("limit"), el.find("mimic")
        lower = _number(limit, "lower", f"joint {jname!r} limit lower")
        upper = _number(limit, "upper", f"joint {jname!r} limit upper")
        effort = _number(limit, "effort", f"joint {jname!r} limit effort")
        axis_el = el.find("axis")
        joints.append(
            _Joint(
                jname,
                jtype,
                parent.get("link") or "",
                child.get("link") or "",
                _origin(el.find("origin"), f"joint {jname!r}"),
                _floats(axis_el.get("xyz") if axis_el is not None else None, 3, f"joint {jname!r} axis", (1, 0, 0)),
                lower,
                upper,
                effort,
                (
                    mimic.get("joint") or "",
                    float(_floats(mimic.get("multiplier", "1"), 1, f"joint {jname!r} mimic multiplier")[0]),
                    float(_floats(mimic.get("offset", "0"), 1, f"joint {jname!r} mimic offset")[0]),
                )
                if mimic is not None
                else None,
            )
        )
    return links, joints


def _shape(el: ET.Element, link: str, path: Path, packages: dict[str, Any]) -> trimesh.Trimesh:
    what = f"link {link!r}"
    shape: trimesh.Trimesh  # trimesh.creation's functions are unannotated
    if el.tag == "box":
        shape = trimesh.creation.box(extents=_floats(el.get("size"), 3, f"{what} box size"))
        return shape
    if el.tag == "cylinder":
        r = _floats(el.get("radius"), 1, f"{what} cylinder radius")[0]
        h = _floats(el.get("length"), 1, f"{what} cylinder length")[0]
        shape = trimesh.creation.cylinder(radius=r, height=h, sections=48)
        return shape
    if el.tag == "sphere":
        shape = trimesh.creation.icosphere(subdivisions=3, radius=_floats(el.get("radius"), 1, f"{what} radius")[0])
        return shape
    if el.tag != "mesh":
        raise InvalidGripperError(
            f"{what} has geometry <{el.tag}>, which is not imported (mesh, box, cylinder, sphere)"
        )
    filename = el.get("filename") or ""
    file = _resolve(filename, path, packages, what)
    ext = file.suffix.lower().lstrip(".")
    if ext not in ("stl", "obj", "ply", "off", "glb"):
        raise InvalidGripperError(f"{what}: mesh {filename!r} is .{ext}: convert it to STL, OBJ, PLY, OFF or GLB")
    try:
        mesh = trimesh.load(file, file_type=ext, force="mesh", process=False)
    except Exception as exc:  # trimesh's readers raise anything
        raise InvalidGripperError(f"{what}: cannot read mesh {filename!r}: {type(exc).__name__}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidGripperError(f"{what}: mesh {filename!r} holds no triangles")
    scale = _floats(el.get("scale"), 3, f"{what} mesh scale", (1.0, 1.0, 1.0))
    return trimesh.Trimesh(np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces), process=False)


def _resolve(filename: str, urdf: Path, packages: dict[str, Any], what: str) -> Path:
    tried: list[Path] = []
    if filename.startswith("package://"):
        package, _, rel = filename[len("package://") :].partition("/")
        if package in packages:
            tried.append(Path(packages[package]) / rel)
        tried += [d / rel for d in urdf.resolve().parents if d.name == package]
        tried += [urdf.parent / rel, urdf.parent / Path(rel).name]
    elif filename.startswith("file://"):
        tried.append(Path(filename[len("file://") :]))
    elif filename:
        tried.append(urdf.parent / filename)
    for candidate in tried:
        if candidate.is_file():
            return candidate
    where = ", ".join(str(t) for t in tried) or "nowhere"
    raise InvalidGripperError(f"{what}: mesh {filename!r} is missing (looked at {where})")


# -- the gripper -------------------------------------------------------------------------------------------------------
def _gripper(
    root: ET.Element,
    links: dict[str, _Link],
    joints: list[_Joint],
    *,
    name: str | None,
    friction: float,
    clearance: float,
    approach: tuple[float, float, float] | None,
) -> tuple[dict[str, Any], dict[str, bytes]]:
    children = {j.child for j in joints}
    roots = [n for n in links if n not in children]
    if len(roots) != 1:
        raise InvalidGripperError(f"the URDF's links form {len(roots)} trees ({', '.join(roots[:4])}), not one")
    moving = [j for j in joints if j.type in _MOVING]
    other = [j for j in moving if j.type != "prismatic"]
    if other:
        j = other[0]
        raise InvalidGripperError(
            f"joint {j.name!r} is {j.type}: only parallel grippers whose two fingers slide on prismatic joints are "
            "imported"
        )
    unknown = [j for j in joints if j.type not in _MOVING and j.type != "fixed"]
    if unknown:
        raise InvalidGripperError(f"joint {unknown[0].name!r} has an unknown type {unknown[0].type!r}")
    if len(moving) != 2:
        count = "no" if not moving else "only one" if len(moving) == 1 else f"{len(moving)}"
        raise InvalidGripperError(
            f"the URDF has {count} prismatic joint{'s' if len(moving) != 1 else ''}: a parallel gripper has two "
            "fingers, each on its own prismatic joint"
        )
    T = _forward(roots[0], joints)
    subtree = {j.name: _subtree(j.child, joints) for j in moving}
    a, b = moving
    if subtree[a.name] & subtree[b.name]:
        raise InvalidGripperError(f"finger joints {a.name!r} and {b.name!r} are in series, not side by side")
    fingers = [_vertices_faces(subtree[j.name], links, T) for j in moving]
    for j, (v, _) in zip(moving, fingers, strict=True):
        if len(v) == 0:
            raise InvalidGripperError(f"the finger of joint {j.name!r} has no collision or visual geometry")
    in_fingers = subtree[a.name] | subtree[b.name]
    body = _vertices_faces([n for n in links if n not in in_fingers], links, T)

    # axes in the root frame; the closing axis X from the -X finger to the +X one
    axes = []
    for j in moving:
        n = float(np.linalg.norm(j.axis))
        if n == 0:
            raise InvalidGripperError(f"joint {j.name!r} has a zero axis")
        axes.append(T[j.parent][:3, :3] @ j.origin[:3, :3] @ (j.axis / n))
    cos = abs(float(axes[0] @ axes[1]))
    if cos < math.cos(math.radians(AXIS_TOLERANCE_DEG)):
        angle = math.degrees(math.acos(min(cos, 1.0)))
        raise InvalidGripperError(
            f"the finger joints' axes are {angle:.1f} deg apart: a parallel gripper's fingers slide along one axis"
        )
    X = axes[0]
    centre = [v.mean(axis=0) @ X for v, _ in fingers]
    if abs(centre[0] - centre[1]) < FRAME_TOLERANCE:
        raise InvalidGripperError(
            "the two fingers lie at the same place along their axis: the closing axis cannot be told"
        )
    if centre[0] < centre[1]:
        X = -X
    right, left = (0, 1) if centre[0] > centre[1] else (1, 0)

    Z = _approach(approach, fingers, body, X)
    Y = np.cross(Z, X)
    R = np.column_stack([X, Y, Z])
    pads = []
    for k, sign in ((right, -1.0), (left, 1.0)):  # the +X finger's inner face is its lowest x, the -X finger's highest
        p = fingers[k][0] @ R  # (n, 3) in X, Y, Z coordinates
        inner = p[:, 0].min() if sign < 0 else p[:, 0].max()
        face = p[np.abs(p[:, 0] - inner) <= FRAME_TOLERANCE]
        pads.append(
            np.array([inner, (face[:, 1].min() + face[:, 1].max()) / 2, (face[:, 2].min() + face[:, 2].max()) / 2])
        )
    if np.abs(pads[0][1:] - pads[1][1:]).max() > PAD_ALIGNMENT:
        raise InvalidGripperError(
            f"the fingers' pads do not face each other: their centres differ by "
            f"{np.abs(pads[0][1:] - pads[1][1:]).max() * 1e3:.3g} mm across the closing axis"
        )
    yz = (pads[0][1:] + pads[1][1:]) / 2
    c_right, c_left = (np.array([pads[i][0], *yz]) for i in (0, 1))
    w0 = float(c_right[0] - c_left[0])
    w_min, w_max, effort = _travel(moving[right], moving[left], axes[right] @ X, axes[left] @ X, w0, joints)
    if not w_max > max(w_min, 0.0):
        raise InvalidGripperError(f"the fingers open to {w_max * 1e3:.4g} mm at most: no stroke")
    origin = (c_right + c_left) / 2  # in X, Y, Z coordinates

    def in_frame(v: np.ndarray, o: np.ndarray, flip: bool) -> np.ndarray:
        p: np.ndarray = v @ R - o
        return p * np.array([-1.0, -1.0, 1.0]) if flip else p

    finger_mesh = (in_frame(fingers[right][0], c_right, False), fingers[right][1])
    left_mesh = (in_frame(fingers[left][0], c_left, True), fingers[left][1])
    slug = _slug(name or root.get("name") or "gripper")
    files = {f"{slug}-finger.stl": stl_bytes(finger_mesh)}
    geometry: dict[str, Any] = {"units": "m", "finger": f"{slug}-finger.stl"}
    if _canonical(left_mesh) != _canonical(finger_mesh):  # mirror fingers: one file serves both
        files[f"{slug}-finger-left.stl"] = stl_bytes(left_mesh)
        geometry["finger_left"] = f"{slug}-finger-left.stl"
    if len(body[0]):
        files[f"{slug}-body.stl"] = stl_bytes((in_frame(body[0], origin, False), body[1]))
        geometry["body"] = f"{slug}-body.stl"
    spec: dict[str, Any] = {
        "name": slug,
        "kind": "parallel",
        "stroke": round(w_max, 9),
        "min_width": round(max(w_min, 0.0), 9),
        "friction": friction,
        "pregrasp_clearance": clearance,
    }
    if effort is not None and effort > 0:
        spec["grip_force"] = effort
    spec["geometry"] = geometry
    return spec, files


def _canonical(mesh: tuple[np.ndarray, np.ndarray]) -> bytes:
    """The mesh's oriented triangles (vertices rounded to 1e-9 m) in a canonical order: equal for the same solid
    however its vertices and faces are numbered."""
    v, f = mesh
    tri = np.round(v[f], 9) + 0.0  # + 0.0 turns -0.0 into 0.0
    first = np.array([min(range(3), key=lambda k: tuple(t[k])) for t in tri], dtype=np.int64)
    rolled = np.stack([tri[np.arange(len(tri)), (first + k) % 3] for k in range(3)], axis=1).reshape(len(tri), 9)
    return rolled[np.lexsort(rolled.T[::-1])].tobytes()


def _forward(root: str, joints: list[_Joint]) -> dict[str, np.ndarray]:
    """T_root_link of every link at the zero configuration."""
    T = {root: np.eye(4)}
    frontier = [root]
    while frontier:
        parent = frontier.pop()
        for j in joints:
            if j.parent == parent:
                if j.child in T:
                    raise InvalidGripperError(f"link {j.child!r} has two parents: the URDF is not a tree")
                T[j.child] = T[parent] @ j.origin
                frontier.append(j.child)
    return T


def _subtree(link: str, joints: list[_Joint]) -> set[str]:
    out, frontier = {link}, [link]
    while frontier:
        parent = frontier.pop()
        for j in joints:
            if j.parent == parent and j.child not in out:
                out.add(j.child)
                frontier.append(j.child)
    return out


def _vertices_faces(
    names: Iterable[str], links: dict[str, _Link], T: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces, offset = [], [], 0
    for n in sorted(names):
        for T_link_shape, mesh in links[n].shapes:
            M = T[n] @ T_link_shape
            v = np.asarray(mesh.vertices) @ M[:3, :3].T + M[:3, 3]
            vertices.append(v)
            faces.append(np.asarray(mesh.faces, dtype=np.int64) + offset)
            offset += len(v)
    if not vertices:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(vertices), np.concatenate(faces)


def _approach(
    given: tuple[float, float, float] | None,
    fingers: list[tuple[np.ndarray, np.ndarray]],
    body: tuple[np.ndarray, np.ndarray],
    X: np.ndarray,
) -> np.ndarray:
    if given is not None:
        d = np.asarray(given, dtype=float)
        what = "the given approach"
    else:
        f = np.concatenate([v for v, _ in fingers])
        f_centre = (f.min(axis=0) + f.max(axis=0)) / 2
        b_centre = (body[0].min(axis=0) + body[0].max(axis=0)) / 2 if len(body[0]) else np.zeros(3)
        d = f_centre - b_centre
        what = "the direction from the body to the fingers"
    d = d - (d @ X) * X
    n = float(np.linalg.norm(d))
    if not n > 1e-9:
        raise InvalidGripperError(
            f"{what} is along the closing axis: the approach cannot be told; give it (--approach x,y,z)"
        )
    unit: np.ndarray = d / n
    return unit


def _travel(
    right: _Joint, left: _Joint, c_right: float, c_left: float, w0: float, joints: list[_Joint]
) -> tuple[float, float, float | None]:
    """(smallest, largest distance between the pads, the driving joint's effort) over the joint limits. The +X finger
    moves outwards by c_right q, the -X finger by -c_left q (c: the joint axis along X)."""
    by_name = {j.name: j for j in joints}
    for j in (right, left):
        if j.mimic is None and (j.lower is None or j.upper is None or not j.lower < j.upper):
            raise InvalidGripperError(
                f"prismatic joint {j.name!r} has no limits (lower < upper): its stroke cannot be known"
            )
    if right.mimic is not None and left.mimic is not None:
        raise InvalidGripperError(f"both finger joints ({right.name!r}, {left.name!r}) are mimics: one must drive")
    if right.mimic is not None or left.mimic is not None:
        follower, leader = (right, left) if right.mimic is not None else (left, right)
        # the leader drives, so the loop above checked its limits
        assert follower.mimic is not None and leader.lower is not None and leader.upper is not None
        if follower.mimic[0] != leader.name:
            target = by_name.get(follower.mimic[0])
            raise InvalidGripperError(
                f"joint {follower.name!r} mimics {follower.mimic[0]!r}"
                + (" (not the other finger joint)" if target else " (no such joint)")
            )
        _, m, off = follower.mimic
        c_lead = c_right if leader is right else -c_left  # outward motion per unit of the leader's q
        c_follow = c_right if follower is right else -c_left
        if abs(c_lead - c_follow * m) > 1e-6 or abs(c_follow * off) > 1e-9:
            raise InvalidGripperError(
                f"joint {follower.name!r} (multiplier {m:g}, offset {off:g}) does not move its finger as far as "
                f"{leader.name!r} moves the other: the fingers do not close symmetrically"
            )
        s = sorted((c_lead * leader.lower, c_lead * leader.upper))
        return w0 + 2 * s[0], w0 + 2 * s[1], leader.effort
    # neither is a mimic: the loop above checked both joints' limits
    assert right.lower is not None and right.upper is not None and left.lower is not None and left.upper is not None
    s_right = sorted((c_right * right.lower, c_right * right.upper))
    s_left = sorted((-c_left * left.lower, -c_left * left.upper))
    if max(abs(s_right[0] - s_left[0]), abs(s_right[1] - s_left[1])) > 1e-6:
        raise InvalidGripperError(
            f"the finger joints {right.name!r} and {left.name!r} have different travel: the fingers do not close "
            "symmetrically (make one a mimic of the other)"
        )
    return w0 + 2 * s_right[0], w0 + 2 * s_right[1], right.effort


def _slug(text: str) -> str:
    s = re.sub(r"[^a-z0-9._-]+", "-", text.strip().lower()).strip("-._")
    return s[:40] or "gripper"


# -- writing -----------------------------------------------------------------------------------------------------------
def _write(spec: dict[str, Any], files: dict[str, bytes], out: Path) -> Path:
    """Write into a temporary folder inside `out`, load the spec from there (every check of a spec with geometry),
    then move the files into place: nothing is left behind when it does not check."""
    made = [d for d in (out, *out.parents) if not d.exists()]
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".import-", dir=out))
    done = False
    try:
        for rel, data in files.items():
            (tmp / rel).write_bytes(data)
        spec_name = f"{spec['name']}.json"
        (tmp / spec_name).write_text(json.dumps(spec, indent=2) + "\n", encoding="utf-8")
        try:
            GripperSpec.load(tmp / spec_name)
        except GraspgenError as exc:
            raise InvalidGripperError(f"the imported gripper does not check: {exc.message}", field=exc.field) from None
        for rel in (*files, spec_name):
            os.replace(tmp / rel, out / rel)
        done = True
        return out / spec_name
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(tmp)
        if not done:  # a refused import leaves no folder it made behind
            for d in made:
                with contextlib.suppress(OSError):
                    d.rmdir()
