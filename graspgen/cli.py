"""`graspgen` command line: generate, demo, render, gripper import, warmup; serve / worker / migrate start the
service, found through the entry-point group `graspgen.service` (the library never imports it; `pip install
'graspgen[service]'` installs it).

Exit status: 0 success, 2 bad input (one-line reason on stderr, no output written), 1 internal error.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
import traceback
import uuid
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, cast

from .errors import Cancelled, GraspgenError, InvalidUnitsError
from .examples import EXAMPLE_GRIPPER
from .params import Params, QualityOptions, param_options
from .units import UNIT_SCALE

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from .export import GraspSet
    from .suction import SuctionGraspSet

__all__ = ["main", "DEMO_GRIPPER"]

#: the gripper of the demo: the contract's example (a PGN-80-like parallel gripper)
DEMO_GRIPPER: dict[str, Any] = dict(EXAMPLE_GRIPPER)


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse exits 2 as well; keep the message to one line
        raise _UsageError(message)


def _add_run_options(
    p: argparse.ArgumentParser, params_cls: type[Params] = Params, options_cls: type[QualityOptions] = QualityOptions
) -> None:
    """Every run parameter of Params and the job options of QualityOptions, as their types and metadata declare them
    (params.py `_option`): a new field of Params is a new option here."""
    quality = [o for o in param_options(options_cls) if o.name in options_cls.JOB_OPTIONS]
    groups: dict[str, Any] = {}  # mutually exclusive groups by name
    for o in (*param_options(params_cls), *quality):
        flag = o.flag or "--" + o.name.replace("_", "-")
        target = p
        if o.exclusive:
            if o.exclusive not in groups:
                groups[o.exclusive] = p.add_mutually_exclusive_group()
            target = groups[o.exclusive]
        if o.kind is bool:
            target.add_argument(flag, dest=o.name, action="store_true", help=o.help)
            continue
        # `float | None`: None is the default, never typed on the command line
        shown = "" if o.default is None else " (default %(default)s)"
        target.add_argument(
            flag,
            dest=o.name,
            type=o.kind,
            choices=o.choices,
            default=o.default,
            metavar=None if o.choices else flag[2:].replace("-", "_").upper(),
            help=o.help + shown,
        )


def _parser(
    params_cls: type[Params] = Params, options_cls: type[QualityOptions] = QualityOptions
) -> argparse.ArgumentParser:
    """The command line; its run options are the fields of `params_cls` and `options_cls` (_add_run_options)."""
    parser = _Parser(prog="graspgen", description="Grasp poses for parallel-jaw grippers (CONTRACT.md).")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    g = sub.add_parser("generate", help="grasps for one part and gripper")
    g.add_argument("mesh", help="STL/OBJ/PLY/OFF/GLB mesh, or PLY/NPZ point cloud")
    g.add_argument("--units", choices=tuple(UNIT_SCALE), help="the length unit of the file (required)")
    g.add_argument("--gripper", required=True, help="gripper spec JSON (metres)")
    g.add_argument("--name", help="object name in the export (default: the file stem)")
    _add_run_options(g, params_cls, options_cls)
    g.add_argument("--out", required=True, help="grasp_set/1 JSON to write")
    g.add_argument("--candidates", help="candidate NPZ to write")
    g.add_argument("--recording", help="Rerun .rrd to write")
    g.add_argument("--preview", help="PNG picture of the grasps to write")
    g.add_argument("--quiet", action="store_true", help="no summary table")
    d = sub.add_parser("demo", help="grasps for a shipped example part, written to out/demo/")
    d.add_argument("--part", default="ring-screw", help="example part (default ring-screw)")
    _add_run_options(d, params_cls, options_cls)
    d.add_argument("--out-dir", default="out/demo")
    r = sub.add_parser("render", help="PNG picture of a grasp set on its part")
    r.add_argument("grasps", help="grasp_set/1 JSON")
    r.add_argument("--mesh", required=True, help="the part's mesh")
    r.add_argument("--units", required=True, choices=tuple(UNIT_SCALE), help="the length unit of the mesh")
    r.add_argument("--out", required=True, help="PNG to write")
    r.add_argument("--size", default="800x600", help="WIDTHxHEIGHT in pixels (default 800x600)")
    gr = sub.add_parser("gripper", help="gripper specs: import a URDF")
    gsub = gr.add_subparsers(dest="gripper_command", required=True, parser_class=_Parser)
    imp = gsub.add_parser("import", help="a URDF of a parallel gripper -> a spec with geometry and its meshes")
    imp.add_argument("urdf", help="the gripper's URDF (two prismatic finger joints, e.g. one a mimic)")
    imp.add_argument("--out", required=True, help="folder to write <name>.json and its STL meshes into")
    imp.add_argument("--name", help="gripper name (default: the URDF's robot name, as a slug)")
    imp.add_argument("--friction", type=float, default=0.5, help="pad/part friction (default %(default)s)")
    imp.add_argument(
        "--pregrasp-clearance", type=float, default=0.02, help="extra opening before closing, m (default %(default)s)"
    )
    imp.add_argument(
        "--approach", help="approach direction X,Y,Z in the URDF's root link frame (default: body->fingers)"
    )
    imp.add_argument(
        "--package", action="append", default=[], metavar="NAME=DIR", help="folder of a ROS package (package://)"
    )
    w = sub.add_parser("warmup", help="compile every numba kernel into numba's on-disk cache (no cold start)")
    w.add_argument("--quiet", action="store_true", help="print nothing but errors")
    for name in SERVICE_COMMANDS:
        sub.add_parser(name, help=f"service: {name} (see docs/SERVICE.md)", add_help=False)
    return parser


#: the entry-point group the service registers its command line under (pyproject.toml)
SERVICE_GROUP = "graspgen.service"
SERVICE_COMMANDS = ("serve", "worker", "migrate")
SERVICE_MISSING = "graspgen: the service is not installed: pip install 'graspgen[service]'"


def _service_main(argv: list[str], group: str = SERVICE_GROUP) -> int:
    """Run `graspgen serve | worker | migrate` through the service's entry point; exit 2 when it is not installed."""
    from importlib.metadata import entry_points

    found = entry_points(group=group, name="cli")
    try:
        service_main = next(iter(found)).load() if found else None
    except ImportError:  # registered, but the service's dependencies are not installed
        service_main = None
    if service_main is None:
        print(SERVICE_MISSING, file=sys.stderr)
        return 2
    return int(service_main(argv))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SERVICE_COMMANDS:
        return _service_main(argv)
    try:
        args = _parser().parse_args(argv)
    except _UsageError as exc:
        print(f"graspgen: error: {exc}", file=sys.stderr)
        return 2
    try:
        if args.command == "generate":
            return _generate(args)
        if args.command == "render":
            return _render(args)
        if args.command == "warmup":
            return _warmup(args)
        if args.command == "gripper":
            return _gripper_import(args)
        return _demo(args)
    except GraspgenError as exc:
        print(f"graspgen: error: {exc.message}", file=sys.stderr)
        return 2
    except Cancelled:
        print("graspgen: cancelled", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("graspgen: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: say so plainly, with the traceback for a bug report
        traceback.print_exc()
        print(f"graspgen: internal error: {exc}", file=sys.stderr)
        return 1


def _run_kwargs(args: argparse.Namespace, params_cls: type[Params] = Params) -> dict[str, Any]:
    """The parsed run parameters by field name (Params(**these))."""
    return {f.name: getattr(args, f.name) for f in fields(params_cls)}


def _quality_kwargs(args: argparse.Namespace, options_cls: type[QualityOptions] = QualityOptions) -> dict[str, Any]:
    """The parsed job options by field name (QualityOptions(**these))."""
    return {k: getattr(args, k) for k in options_cls.JOB_OPTIONS}


def _run_params(
    args: argparse.Namespace, params_cls: type[Params] = Params, options_cls: type[QualityOptions] = QualityOptions
) -> tuple[Params, QualityOptions]:
    """The parsed options as the run's Params and QualityOptions (InvalidParameterError: exit 2)."""
    return params_cls(**_run_kwargs(args, params_cls)), options_cls(**_quality_kwargs(args, options_cls))


def _preview_of(mesh_path: str, units: str) -> Callable[[GraspSet], bytes]:
    """A function result -> PNG bytes drawing the result on the part (a point cloud: on its convex hull)."""

    def preview(result: GraspSet) -> bytes:
        from .parts import load_part
        from .render import render_grasp_set

        return render_grasp_set(
            load_part(mesh_path, units=units).surface_mesh(), result.to_json(), gripper=result.gripper
        )

    return preview


def _render(args: argparse.Namespace) -> int:
    import json

    from .export import write_atomic
    from .parts import load_part
    from .render import parse_size, render_grasp_set

    size = parse_size(args.size)
    try:
        export = json.loads(Path(args.grasps).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise GraspgenError(f"cannot read grasp set {args.grasps}: {exc}") from None
    if not isinstance(export, dict) or "grasps" not in export or "gripper" not in export:
        raise GraspgenError(f"{args.grasps} is not a grasp_set/1 export")
    mesh = load_part(args.mesh, units=args.units).surface_mesh()
    write_atomic(args.out, render_grasp_set(mesh, export, size=size))
    print(f"wrote {args.out} ({size[0]}x{size[1]}, {len(export['grasps'])} grasps)")
    return 0


def _gripper_import(args: argparse.Namespace) -> int:
    from .urdf import import_urdf

    approach: tuple[float, float, float] | None = None
    if args.approach is not None:
        try:
            xyz = tuple(float(v) for v in args.approach.split(","))
        except ValueError:
            xyz = ()
        if len(xyz) != 3:
            raise GraspgenError(f"--approach must be three numbers X,Y,Z, got {args.approach!r}")
        approach = xyz
    packages = {}
    for item in args.package:
        name, sep, folder = item.partition("=")
        if not sep or not name or not folder:
            raise GraspgenError(f"--package must be NAME=DIR, got {item!r}")
        packages[name] = folder
    spec_path = import_urdf(
        args.urdf,
        args.out,
        name=args.name,
        friction=args.friction,
        pregrasp_clearance=args.pregrasp_clearance,
        approach=approach,
        packages=packages,
    )
    from .gripper import GripperSpec

    spec = GripperSpec.load(spec_path)
    assert spec.geometry is not None  # import_urdf writes a spec with geometry
    files = ", ".join(sorted(spec.geometry.sha256))
    print(f"wrote {spec_path} ({files}): stroke {spec.stroke * 1e3:.4g} mm, min_width {spec.min_width * 1e3:.4g} mm")
    return 0


def _warmup(args: argparse.Namespace) -> int:
    from .warmup import warmup

    def say(step: str) -> None:
        if not args.quiet:
            print(f"warmup: {step}", file=sys.stderr, flush=True)

    res = warmup(log=say)
    if not args.quiet:
        print(
            f"kernels compiled and cached in {res['cache_dir']} ({res['index_files']} index files), "
            f"{res['seconds']:.1f} s"
        )
    return 0


def _generate(args: argparse.Namespace) -> int:
    from . import pipeline
    from .kinds import load_gripper
    from .suction import SuctionSpec
    from .units import extents_under_each_unit

    spec = load_gripper(args.gripper)  # a parallel gripper or a suction cup, by its kind
    params, options = _run_params(args)  # checked before any heavy work
    if isinstance(spec, SuctionSpec) and args.preview:
        raise GraspgenError("--preview does not draw suction cups yet: leave it out", field="preview")
    if args.units is None:
        from .parts import read_raw_extents

        raw = read_raw_extents(args.mesh)
        raise InvalidUnitsError(
            "--units is required (mm, cm, m or in); this part's extents would be " + extents_under_each_unit(raw)
        )
    outputs = {
        "out": Path(args.out),
        "candidates": args.candidates and Path(args.candidates),
        "recording": args.recording and Path(args.recording),
        "preview": args.preview and Path(args.preview),
    }
    return _run_and_write(
        lambda rec, progress: pipeline.generate(
            args.mesh,
            spec,
            units=args.units,
            recording=rec,
            progress=progress,
            object_name=args.name,
            params=params,
            options=options,
        ),
        outputs,
        quiet=args.quiet,
        preview=_preview_of(args.mesh, args.units) if args.preview else None,
    )


def _demo(args: argparse.Namespace) -> int:
    from . import pipeline
    from .examples import EXAMPLES, example_part

    if args.part not in EXAMPLES:
        raise GraspgenError(f"unknown example part {args.part!r}: choose one of {', '.join(EXAMPLES)}")
    out = Path(args.out_dir)
    outputs = {"out": out / "grasps.json", "candidates": out / "candidates.npz", "recording": out / "run.rrd"}
    part = example_part(args.part)
    print(
        f"graspgen demo: part {args.part!r} ({' x '.join(f'{e * 1e3:.0f}' for e in part.extents)} mm), "
        f"gripper {DEMO_GRIPPER['name']!r}, {args.points} points",
        file=sys.stderr,
    )

    def run(rec: Any, progress: Any) -> Any:
        params, options = _run_params(args)
        return pipeline.generate(part, DEMO_GRIPPER, recording=rec, progress=progress, params=params, options=options)

    code = _run_and_write(run, outputs, quiet=False)
    if code == 0:
        print(
            f"wrote {outputs['out']}, {outputs['candidates']} and {outputs['recording']} "
            f"(open the recording with: rerun {outputs['recording']})"
        )
    return code


def _run_and_write(
    run: Callable[[Path | None, _ProgressBar], GraspSet | SuctionGraspSet],
    outputs: Mapping[str, Path | None],
    *,
    quiet: bool,
    preview: Callable[[GraspSet], bytes] | None = None,
) -> int:
    """Run, then move every output into place only when all of them were written: nothing half-done."""
    tag = uuid.uuid4().hex[:8]
    temps: dict[str, Path] = {}
    made: list[Path] = []  # directories this run created: removed again when it fails
    for key, path in outputs.items():
        if path is not None:
            made += [d for d in (path.parent, *path.parent.parents) if not d.exists() and d not in made]
            path.parent.mkdir(parents=True, exist_ok=True)
            temps[key] = path.with_name(f".{path.name}.{tag}.tmp")
    bar = _ProgressBar(enabled=sys.stderr.isatty() and not quiet)
    done = False
    try:
        result = run(temps.get("recording"), bar)
        bar.close()
        result.save(temps["out"])
        if "candidates" in temps:
            result.save_candidates(temps["candidates"])
        if "preview" in temps:
            assert preview is not None  # a preview output comes with its function
            from .suction import SuctionGraspSet

            assert not isinstance(result, SuctionGraspSet)  # _generate refuses a preview of suction cups
            temps["preview"].write_bytes(preview(result))
        for key, tmp in temps.items():
            os.replace(tmp, cast(Path, outputs[key]))  # temps holds only the outputs that were given
        done = True
    finally:
        bar.close()
        for tmp in temps.values():
            tmp.unlink(missing_ok=True)
        if not done:  # bad input writes nothing, not even the output's directory
            for d in sorted(made, key=lambda p: len(p.parts), reverse=True):
                with contextlib.suppress(OSError):
                    d.rmdir()
    for warning in result.stats.get("warnings", []):
        print(f"graspgen: warning: {warning}", file=sys.stderr)
    if not quiet:
        print(_summary(result))
    if not result.grasps:
        reason = result.stats.get("empty_reason", {})
        print(f"graspgen: no grasps: {reason.get('message', 'no candidate survived')}", file=sys.stderr)
    return 0


class _ProgressBar:
    """One line on stderr, only on a terminal."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.open = False

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        width = 24
        done = int(round(fraction * width))
        sys.stderr.write(f"\r{stage:<10} [{'#' * done}{'.' * (width - done)}] {time.perf_counter() - self.t0:6.1f} s")
        sys.stderr.flush()
        self.open = True

    def close(self) -> None:
        if self.open:
            sys.stderr.write("\n")
            self.open = False


def _summary(result: GraspSet | SuctionGraspSet) -> str:
    from .suction import SuctionGraspSet

    if isinstance(result, SuctionGraspSet):
        return _suction_summary(result)
    s = result.stats
    rej = s["rejected"]
    t = s["timings_s"]
    rows = [
        ("object", f"{result.object['name']} ({result.object['source_units']})"),
        ("gripper", result.gripper.name),
        ("points", f"{s['points']} (mean spacing {s.get('spacing_mean', 0) * 1e3:.2f} mm)"),
        ("pairs", f"{s['pairs_total']:,}"),
        ("rejected: stroke", f"{rej['stroke']:,}"),
        ("rejected: outside", f"{rej['outside']:,}"),
        ("rejected: friction", f"{rej['friction']:,}"),
        ("rejected: collision", f"{rej['collision']:,}"),
        ("rejected: hold", f"{rej['hold']:,}" if "hold" in s else "off"),
        ("candidates", f"{s['candidates']:,}"),
        ("grasps", f"{len(result.grasps)}"),
        *_quality_rows(s),
        ("time", " ".join(f"{k} {v:.2f}s" for k, v in t.items())),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def _suction_summary(result: SuctionGraspSet) -> str:
    s = result.stats
    rows = [
        ("object", f"{result.object['name']} ({result.object['source_units']})"),
        ("gripper", f"{result.gripper.name} (suction, cup {2 * result.gripper.cup_radius * 1e3:.4g} mm)"),
        ("points", f"{s['points']} (mean spacing {s.get('spacing_mean', 0) * 1e3:.2f} mm)"),
        ("approaches", f"{s['candidates_total']:,}"),
        *((f"rejected: {k}", f"{v:,}" if k != "hold" or "hold" in s else "off") for k, v in s["rejected"].items()),
        ("candidates", f"{s['candidates']:,}"),
        ("grasps", f"{len(result.grasps)}"),
        *_quality_rows(s),
        ("time", " ".join(f"{k} {v:.2f}s" for k, v in s["timings_s"].items())),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def _quality_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    rows = []
    cov = s.get("coverage")
    if cov:
        rows.append(
            (
                "coverage",
                ", ".join(
                    f"{lv['share']:.1%} at {lv['radius'] * 100:g} cm/{lv['angle_deg']:g} deg" for lv in cov["levels"]
                ),
            )
        )
    sel = s.get("selection")
    if sel:
        rows.append(
            ("selection", f"{sel['mode']}: {sel['replaced']} replaced, mean score {sel['mean_score_selected']}")
        )
    v = s.get("validation")
    if v:
        fails = ", ".join(f"{k} {n}" for k, n in v["failures"].items() if n)
        rows.append(
            (
                "validation",
                f"{v['succeeded']}/{v['tested']} held ({v['repaired']} repaired)"
                + (f"; failed: {fails}" if fails else ""),
            )
        )
    return rows


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
