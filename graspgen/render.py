"""Pictures of a grasp set: the part shaded, the selected grippers at their poses in cluster colours, four views. A
parallel gripper is drawn as its fingers (at the grasp's width) and palm or body; a suction cup as the cup (a
cylinder from the lip at the contact back along -Z) and the tool behind it (a cylinder, or its body mesh).

Headless by construction: a small z-buffer rasteriser (numba) with flat Lambert shading under a headlight, silhouette
outlines from depth jumps, 2x supersampling, written to PNG with Pillow. No GPU, display, OpenGL/EGL/OSMesa or
download is involved, so it runs the same on a server, in CI and in a worker (docs/QUALITY.md says why not
pyrender or MuJoCo's renderer). Orthographic views, object +Z up: an isometric view, front (-Y), side (+X) and top.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable
from typing import Any

import numpy as np
import trimesh
from numba import njit

from .gripper import GripperSpec
from .kinds import gripper_from_dict
from .recording import cluster_colours
from .suction import SuctionSpec

__all__ = ["VIEWS", "DEFAULT_SIZE", "render_grasp_set", "render_image", "gripper_triangles", "suction_triangles"]

#: the fixed viewpoints: name, direction from the scene towards the camera, the image's up direction
VIEWS: tuple[tuple[str, tuple[float, float, float], tuple[float, float, float]], ...] = (
    ("iso", (1.0, -1.2, 0.9), (0.0, 0.0, 1.0)),
    ("front", (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    ("side", (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    ("top", (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
)
#: a view of VIEWS; a layer of triangles: vertices (v, 3), faces (f, 3), colours (f, 3)
_View = tuple[str, tuple[float, float, float], tuple[float, float, float]]
_Layer = tuple[np.ndarray, np.ndarray, np.ndarray]
#: (width, height) in pixels
DEFAULT_SIZE = (800, 600)
#: the largest image side accepted (pixels)
MAX_SIDE = 4096
_PART_COLOUR = (0.72, 0.72, 0.70)
_BACKGROUND = (1.0, 1.0, 1.0)
_AMBIENT = 0.35
_DIFFUSE = 0.65
#: rendered at this multiple of the tile size, then averaged down (anti-aliasing)
_SUPERSAMPLE = 2
#: the scene's bounding sphere fills this share of the smaller tile side
_FILL = 0.9
#: a depth jump larger than this share of the scene radius between neighbouring pixels draws an outline
_OUTLINE_JUMP = 0.02
_OUTLINE_DARKEN = 0.45
#: grippers in front of the part are drawn see-through with this opacity, behind it faintly
_GRIPPER_ALPHA = 0.6
_HIDDEN_ALPHA = 0.12
#: sides of the polygons that draw a suction cup's and tool's cylinders
_CYLINDER_SECTIONS = 32


@njit(cache=True, nogil=True)
def _raster(
    xy: np.ndarray, depth_v: np.ndarray, faces: np.ndarray, colours: np.ndarray, zbuf: np.ndarray, img: np.ndarray
) -> None:
    """Rasterise triangles (vertex screen coords xy (n, 2), depth (n,), faces (m, 3), colours (m, 3)) into the
    z-buffer zbuf (H, W) and image img (H, W, 3); smaller depth is nearer."""
    H, W = zbuf.shape
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        x0, y0, z0 = xy[a, 0], xy[a, 1], depth_v[a]
        x1, y1, z1 = xy[b, 0], xy[b, 1], depth_v[b]
        x2, y2, z2 = xy[c, 0], xy[c, 1], depth_v[c]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        xmin = max(int(math.floor(min(x0, x1, x2))), 0)
        xmax = min(int(math.ceil(max(x0, x1, x2))), W - 1)
        ymin = max(int(math.floor(min(y0, y1, y2))), 0)
        ymax = min(int(math.ceil(max(y0, y1, y2))), H - 1)
        inv = 1.0 / area
        for py in range(ymin, ymax + 1):
            sy = py + 0.5
            for px in range(xmin, xmax + 1):
                sx = px + 0.5
                w0 = ((x1 - sx) * (y2 - sy) - (x2 - sx) * (y1 - sy)) * inv
                w1 = ((x2 - sx) * (y0 - sy) - (x0 - sx) * (y2 - sy)) * inv
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z < zbuf[py, px]:
                    zbuf[py, px] = z
                    img[py, px, 0] = colours[f, 0]
                    img[py, px, 1] = colours[f, 1]
                    img[py, px, 2] = colours[f, 2]


def gripper_triangles(spec: GripperSpec, T_object_grasp: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) and faces (f, 3) of the gripper's solids (fingers at `width`, palm or body: boxes, or the
    meshes of a gripper from CAD) in the object frame."""
    verts: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    solids = spec.solids()
    if solids.meshes is not None:
        for m in solids.trimeshes(width):
            faces.append(np.asarray(m.faces) + sum(len(x) for x in verts))
            verts.append(np.asarray(m.vertices) @ T_object_grasp[:3, :3].T + T_object_grasp[:3, 3])
    for box in spec.boxes(width) if solids.meshes is None else ():
        b = trimesh.creation.box(extents=box.extents)
        v = b.vertices + np.asarray(box.center)
        faces.append(b.faces + sum(len(x) for x in verts))
        verts.append(v @ T_object_grasp[:3, :3].T + T_object_grasp[:3, 3])
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(verts), np.vstack(faces).astype(np.int64)


def suction_triangles(spec: SuctionSpec, T_object_grasp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) and faces (f, 3) of a suction cup and its tool in the object frame: the cup a cylinder of
    cup_radius from the lip (z = 0 of the grasp frame, at the contact) back to -cup_height, the tool a cylinder from
    there back by its length, or its body mesh (grasp frame)."""
    h = spec.cup_height
    cup = trimesh.creation.cylinder(radius=spec.cup_radius, height=h, sections=_CYLINDER_SECTIONS)
    parts = [(np.asarray(cup.vertices) + (0.0, 0.0, -h / 2), np.asarray(cup.faces))]
    if spec.tool is not None:
        length = spec.tool.length
        tool = trimesh.creation.cylinder(radius=spec.tool.radius, height=length, sections=_CYLINDER_SECTIONS)
        parts.append((np.asarray(tool.vertices) + (0.0, 0.0, -h - length / 2), np.asarray(tool.faces)))
    else:
        assert spec.geometry is not None  # a suction spec has a tool or a body
        parts.append((np.asarray(spec.geometry.vertices), np.asarray(spec.geometry.faces)))
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v @ T_object_grasp[:3, :3].T + T_object_grasp[:3, 3])
        faces.append(f + offset)
        offset += len(v)
    return np.vstack(verts), np.vstack(faces).astype(np.int64)


def _layers(
    mesh: trimesh.Trimesh, export: dict[str, Any], gripper: GripperSpec | SuctionSpec | None = None
) -> tuple[_Layer, _Layer]:
    """Two layers of triangles, the part and the grippers: each (vertices (v, 3), faces (f, 3), colours (f, 3))."""
    part = (
        np.asarray(mesh.vertices, dtype=np.float64),
        np.asarray(mesh.faces, dtype=np.int64),
        np.tile(_PART_COLOUR, (len(mesh.faces), 1)),
    )
    verts, faces, cols = [np.zeros((0, 3))], [np.zeros((0, 3), dtype=np.int64)], [np.zeros((0, 3))]
    grasps = export.get("grasps") or []
    if grasps:
        spec = gripper if gripper is not None else gripper_from_dict(export["gripper"])
        palette = cluster_colours(np.array([g["cluster"][0] for g in grasps])) / 255.0
        offset = 0
        for g, colour in zip(grasps, palette, strict=True):
            pose = np.asarray(g["pose"], dtype=np.float64)
            if isinstance(spec, SuctionSpec):
                v, f = suction_triangles(spec, pose)
            else:
                v, f = gripper_triangles(spec, pose, float(g["width"]))
            verts.append(v)
            faces.append(f + offset)
            cols.append(np.tile(colour, (len(f), 1)))
            offset += len(v)
    return part, (np.vstack(verts), np.vstack(faces), np.vstack(cols))


def _tile(part: _Layer, grippers: _Layer, centre: np.ndarray, radius: float, view: _View, w: int, h: int) -> np.ndarray:
    """One view as (h, w, 3) float in 0..1: the part, and the grippers over it, see-through where in front."""
    W, H = w * _SUPERSAMPLE, h * _SUPERSAMPLE
    zp, ip = _layer(*part, centre, radius, view, W, H)
    zg, ig = _layer(*grippers, centre, radius, view, W, H)
    img = ip.copy()
    front = zg < zp
    img[front] = _GRIPPER_ALPHA * ig[front] + (1.0 - _GRIPPER_ALPHA) * ip[front]
    behind = np.isfinite(zg) & ~front
    img[behind] = _HIDDEN_ALPHA * ig[behind] + (1.0 - _HIDDEN_ALPHA) * ip[behind]
    tile: np.ndarray = img.reshape(h, _SUPERSAMPLE, w, _SUPERSAMPLE, 3).mean(axis=(1, 3))
    return tile


def _layer(
    verts: np.ndarray,
    faces: np.ndarray,
    base: np.ndarray,
    centre: np.ndarray,
    radius: float,
    view: _View,
    W: int,
    H: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) (inf where empty) and outlined, shaded colour (H, W, 3) of one layer of triangles."""
    _, towards_camera, up_hint = view
    back = np.asarray(towards_camera, dtype=np.float64)
    back /= np.linalg.norm(back)
    d = -back  # looking direction
    right = np.cross(d, np.asarray(up_hint, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    scale = _FILL * min(W, H) / (2.0 * radius)
    rel = verts - centre
    xy = np.column_stack([W / 2 + (rel @ right) * scale, H / 2 - (rel @ up) * scale])
    depth = rel @ d
    # flat Lambert shading under a headlight; two-sided, so a flipped face still reads as a surface
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    shade = _AMBIENT + _DIFFUSE * np.abs(n @ d)
    colours = np.clip(base * shade[:, None], 0.0, 1.0)
    zbuf = np.full((H, W), np.inf)
    img = np.empty((H, W, 3))
    img[:] = _BACKGROUND
    _raster(np.ascontiguousarray(xy), np.ascontiguousarray(depth), faces, colours, zbuf, img)
    # outlines where the depth jumps (silhouettes and creases between bodies)
    finite = np.where(np.isfinite(zbuf), zbuf, 1e9)
    jump = _OUTLINE_JUMP * radius
    edge = np.zeros((H, W), dtype=bool)
    edge[:, 1:] |= np.abs(finite[:, 1:] - finite[:, :-1]) > jump
    edge[1:, :] |= np.abs(finite[1:, :] - finite[:-1, :]) > jump
    img[edge] *= _OUTLINE_DARKEN
    return zbuf, img


def render_image(
    mesh: trimesh.Trimesh,
    export: dict[str, Any],
    *,
    size: tuple[int, int] = DEFAULT_SIZE,
    gripper: GripperSpec | SuctionSpec | None = None,
) -> np.ndarray:
    """The picture as an (H, W, 3) uint8 array: the four `VIEWS` in a 2 x 2 grid, each labelled. `gripper`: the
    export's gripper spec (either kind), needed when it has geometry (the export names its mesh files, it does not
    hold them)."""
    from PIL import Image, ImageDraw

    W, H = _check_size(size)
    part, grippers = _layers(mesh, export, gripper)
    verts = np.vstack([part[0], grippers[0]])
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(verts - centre, axis=1).max()), 1e-9)
    out = np.empty((H, W, 3))
    out[:] = _BACKGROUND
    cols, rows = 2, 2
    xs = np.linspace(0, W, cols + 1).astype(int)
    ys = np.linspace(0, H, rows + 1).astype(int)
    for k, view in enumerate(VIEWS):
        r, c = divmod(k, cols)
        w, h = xs[c + 1] - xs[c], ys[r + 1] - ys[r]
        if w > 0 and h > 0:
            out[ys[r] : ys[r + 1], xs[c] : xs[c + 1]] = _tile(part, grippers, centre, radius, view, w, h)
    image = Image.fromarray(np.round(out * 255).astype(np.uint8), "RGB")
    draw = ImageDraw.Draw(image)
    for k, (name, _, _) in enumerate(VIEWS):
        r, c = divmod(k, cols)
        draw.text((xs[c] + 4, ys[r] + 2), name, fill=(90, 90, 90))
        if c:
            draw.line([(xs[c], ys[r]), (xs[c], ys[r + 1])], fill=(210, 210, 210))
        if r:
            draw.line([(xs[c], ys[r]), (xs[c + 1], ys[r])], fill=(210, 210, 210))
    n = len(export.get("grasps") or [])
    name = (export.get("object") or {}).get("name") or ""
    caption = f"{name}  {n} grasps".strip()
    draw.text((W - 6 * len(caption) - 6, H - 14), caption, fill=(90, 90, 90))
    return np.asarray(image)


def render_grasp_set(
    mesh: trimesh.Trimesh,
    export: dict[str, Any],
    *,
    size: tuple[int, int] = DEFAULT_SIZE,
    gripper: GripperSpec | SuctionSpec | None = None,
) -> bytes:
    """PNG bytes of `export` (a grasp_set/1 dict) drawn on `mesh` (metres, the object's model frame); `gripper` as
    for render_image."""
    from PIL import Image

    buf = io.BytesIO()
    image = render_image(mesh, export, size=size, gripper=gripper)
    Image.fromarray(image, "RGB").save(buf, format="PNG", optimize=False)
    return buf.getvalue()


def _check_size(size: Iterable[Any]) -> tuple[int, int]:
    from .errors import InvalidParameterError

    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"size must be (width, height), got {size!r}", field="size") from None
    if not (16 <= W <= MAX_SIDE and 16 <= H <= MAX_SIDE):
        raise InvalidParameterError(f"image sides must be 16..{MAX_SIDE} pixels, got {W} x {H}", field="size")
    return W, H


def parse_size(text: str) -> tuple[int, int]:
    """'800x600' -> (800, 600)."""
    from .errors import InvalidParameterError

    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise InvalidParameterError(f"size must look like 800x600, got {text!r}", field="size")
    return _check_size((int(parts[0]), int(parts[1])))
