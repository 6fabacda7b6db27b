#!/usr/bin/env python
"""Write the CAD example grippers into examples/ (graspgen/example_grippers.py) and the picture of the finger and
body frames into docs/gripper-frames.svg. tests/graspgen/test_example_grippers.py checks that this reproduces the
committed files byte for byte.

Usage: .venv/bin/python scripts/make_example_grippers.py [--check]   (--check: compare only; exit 1 on a difference)
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from graspgen.example_grippers import EXAMPLE_GRIPPERS, example_gripper_files  # noqa: E402


def expected_files() -> dict[Path, bytes]:
    """Every file this script writes, by its path in the repository."""
    out = {ROOT / "docs" / "gripper-frames.svg": frames_svg().encode()}
    for name in EXAMPLE_GRIPPERS:
        out.update({ROOT / "examples" / rel: data for rel, data in example_gripper_files(name).items()})
    return out


# -- the picture of the frames (docs/API.md): plain SVG from the V-groove example's numbers -------------------------
_S = 4.0  # pixels per millimetre


def _poly(points, fill: str, ox: float, oy: float) -> str:
    pts = " ".join(f"{ox + x * _S:.1f},{oy - y * _S:.1f}" for x, y in points)
    return f'<polygon points="{pts}" fill="{fill}" stroke="#333" stroke-width="1.5"/>'


def _arrow(x0: float, y0: float, x1: float, y1: float, colour: str, ox: float, oy: float) -> str:
    """An arrow from (x0, y0) to (x1, y1), millimetres in the panel's frame."""
    return (
        f'<line x1="{ox + x0 * _S:.1f}" y1="{oy - y0 * _S:.1f}" x2="{ox + x1 * _S:.1f}" y2="{oy - y1 * _S:.1f}" '
        f'stroke="{colour}" stroke-width="2.5" marker-end="url(#head-{colour[1:]})"/>'
    )


def _text(x: float, y: float, text: str, ox: float, oy: float, colour: str = "#000", anchor: str = "start") -> str:
    return f'<text x="{ox + x * _S:.1f}" y="{oy - y * _S:.1f}" fill="{colour}" text-anchor="{anchor}">{text}</text>'


def _dot(x: float, y: float, ox: float, oy: float) -> str:
    return f'<circle cx="{ox + x * _S:.1f}" cy="{oy - y * _S:.1f}" r="3.5" fill="#000"/>'


def frames_svg() -> str:
    red, green, blue = "#c0392b", "#27ae60", "#2c6fbb"
    w, t = 30.0, 14.0  # closing width shown and the finger's thickness, mm
    out = []
    # left panel: side view (X right, Z up) of the grasp frame, both fingers and the body
    ox, oy = 230.0, 210.0
    out.append(_text(0, 36, "side view: the grasp frame (X closing, Z approach)", ox, oy, anchor="middle"))
    out.append(_poly([(w / 2, -15), (w / 2 + t, -15), (w / 2 + t, 15), (w / 2, 15)], "#e8d9b5", ox, oy))
    out.append(_poly([(-w / 2, -15), (-w / 2 - t, -15), (-w / 2 - t, 15), (-w / 2, 15)], "#e8d9b5", ox, oy))
    out.append(_poly([(-39, -35), (39, -35), (39, -15), (-39, -15)], "#cfd8e3", ox, oy))
    out.append(_text(0, -27, "body (in the grasp frame)", ox, oy, anchor="middle"))
    r = 10.0
    out.append(f'<circle cx="{ox}" cy="{oy}" r="{r * _S}" fill="none" stroke="#888" stroke-dasharray="5,4"/>')
    out.append(_arrow(0, 0, 11, 0, red, ox, oy) + _text(2, 2, "X", ox, oy, red))
    out.append(_arrow(0, 0, 0, 24, blue, ox, oy) + _text(1.5, 21, "Z", ox, oy, blue))
    out.append(_dot(0, 0, ox, oy))
    for side in (1, -1):
        x0 = side * w / 2
        out.append(_arrow(x0, 0, x0 + side * (t - 2), 0, red, ox, oy) + _dot(x0, 0, ox, oy))
        out.append(_text(x0 + side * 2, 2, "x", ox, oy, red, "start" if side > 0 else "end"))
        out.append(_text(x0 + side * t / 2, 17, f"{'+' if side > 0 else '-'}X finger", ox, oy, anchor="middle"))
    # right panel: top view (X right, Y up) of one V-groove finger in its own finger frame
    ox, oy = 650.0, 210.0
    out.append(_text(-5, 36, "top view of a V-groove finger in its finger frame", ox, oy, anchor="middle"))
    section = [(0, -12), (14, -12), (14, 12), (0, 12), (0, 8), (8, 0), (0, -8)]
    out.append(_poly(section, "#e8d9b5", ox, oy))
    out.append(
        f'<line x1="{ox:.1f}" y1="{oy - 8 * _S:.1f}" x2="{ox:.1f}" y2="{oy + 8 * _S:.1f}" stroke="#888" '
        'stroke-dasharray="5,4" stroke-width="1.5"/>'
    )
    r = 7.5  # a round part seated on both flanks: its centre lies 8 - r sqrt(2) from the mouth
    out.append(f'<circle cx="{ox + (8 - r * 2**0.5) * _S:.1f}" cy="{oy}" r="{r * _S}" fill="none" stroke="#888"/>')
    out.append(_arrow(0, 0, 24, 0, red, ox, oy) + _text(22, 2, "x", ox, oy, red))
    out.append(_arrow(0, 0, 0, 22, green, ox, oy) + _text(1.5, 20, "y", ox, oy, green))
    out.append(_dot(0, 0, ox, oy))
    out.append(_text(-11, -7, "origin", ox, oy, anchor="end"))
    out.append(_text(0, -16, "the plane spanning the groove's mouth (x = 0)", ox, oy, "#555", "middle"))
    caption = [
        "Finger frame: origin at the pad's contact point (on a V-groove or ridge: the centre of the plane spanning "
        "its mouth);",
        "the finger lies at x >= 0 and its inner face looks along -x; z is the approach direction, as the grasp "
        "frame's Z.",
        "At closing width w (the distance between the pads) the +X finger's frame sits at (+w/2, 0, 0) of the grasp "
        "frame,",
        "the -X finger's at (-w/2, 0, 0) turned 180 deg about Z. The body does not move with the fingers: its mesh "
        "is in the grasp frame.",
    ]
    out += [f'<text x="30" y="{375 + 19 * i}">{line}</text>' for i, line in enumerate(caption)]
    markers = "".join(
        f'<marker id="head-{c[1:]}" markerUnits="userSpaceOnUse" markerWidth="12" markerHeight="12" refX="10" '
        f'refY="6" orient="auto"><path d="M0,1 L11,6 L0,11 z" fill="{c}"/></marker>'
        for c in (red, green, blue)
    )
    return (
        '<svg xmlns="http://www.w3.org/2000/svg" width="900" height="460" viewBox="0 0 900 460" '
        'font-family="sans-serif" font-size="13">\n'
        f"<defs>{markers}</defs>\n"
        '<rect width="900" height="460" fill="#fff"/>\n' + "\n".join(out) + "\n</svg>\n"
    )


def main(argv: list[str]) -> int:
    check = "--check" in argv
    status = 0
    for path, data in expected_files().items():
        rel = path.relative_to(ROOT)
        if check:
            if not path.is_file() or path.read_bytes() != data:
                print(f"differs: {rel}", file=sys.stderr)
                status = 1
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        print(f"wrote {rel}")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
