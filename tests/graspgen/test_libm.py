"""graspgen.libm: the C library's values on every CPU, and no CPU-dispatched numpy transcendental in the library."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np

from graspgen import libm

PACKAGE = Path(__file__).resolve().parents[2] / "graspgen"
#: numpy ufuncs whose float64 loops differ between CPUs (SVML on AVX-512, the C library elsewhere)
DISPATCHED = {"arccos", "arcsin", "arctan", "arctan2", "cos", "sin", "tan", "exp", "log", "power", "cbrt"}


def _inputs() -> np.ndarray:
    rng = np.random.default_rng(7)
    near_one = 1.0 - rng.uniform(0.0, 1e-6, 20_000)  # arccos is steepest here: contacts almost on the axis
    return np.concatenate([rng.uniform(-1.0, 1.0, 100_000), near_one, -near_one, [-1.0, 0.0, 1.0]])


def test_values_are_the_c_librarys_bit_for_bit():
    x = _inputs()
    for f, ref, v in ((libm.arccos, math.acos, x), (libm.cos, math.cos, 7.0 * x), (libm.sin, math.sin, 7.0 * x)):
        assert np.array_equal(f(v), np.array([ref(t) for t in v])), f.__name__
    y = np.random.default_rng(8).normal(size=(20_000, 2))
    want = np.array([math.atan2(a, b) for a, b in y])
    assert np.array_equal(libm.arctan2(y[:, 0], y[:, 1]), want)


def test_values_agree_with_numpy_within_rounding_and_keep_shape():
    x = _inputs()
    np.testing.assert_allclose(libm.arccos(x), np.arccos(x), rtol=1e-14, atol=1e-15)
    grid = np.linspace(-3.0, 3.0, 12).reshape(3, 4, 1)
    assert libm.cos(grid).shape == (3, 4, 1)
    assert isinstance(float(libm.arccos(np.float64(0.5))), float)
    assert math.isclose(float(libm.arccos(np.float64(0.5))), math.pi / 3, rel_tol=1e-15)


def _dispatched_calls(tree: ast.AST) -> list[tuple[int, str]]:
    """np.<DISPATCHED>(...) calls outside functions compiled by numba (whose math is the C library's)."""
    found = []

    def compiled(fn) -> bool:
        return any("jit" in ast.unparse(d) or "vectorize" in ast.unparse(d) for d in fn.decorator_list)

    def walk(node, inside_compiled):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                walk(child, inside_compiled or compiled(child))
                continue
            if (
                not inside_compiled
                and isinstance(child, ast.Call)
                and isinstance(child.func, ast.Attribute)
                and isinstance(child.func.value, ast.Name)
                and child.func.value.id == "np"
                and child.func.attr in DISPATCHED
            ):
                found.append((child.lineno, child.func.attr))
            walk(child, inside_compiled)

    walk(tree, False)
    return found


def test_the_library_computes_no_result_with_a_cpu_dispatched_numpy_ufunc():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for line, name in _dispatched_calls(ast.parse(path.read_text(encoding="utf-8"))):
            offenders.append(f"{path.relative_to(PACKAGE.parent)}:{line} np.{name}")
    assert not offenders, "use graspgen.libm (the same bits on every CPU): " + ", ".join(offenders)


def test_the_check_finds_a_dispatched_call_and_spares_compiled_code():
    src = (
        "import numpy as np\n"
        "from numba import njit\n"
        "def plain(x):\n    return np.arccos(x)\n"
        "@njit(cache=True)\ndef kernel(x):\n    return np.arccos(x)\n"
    )
    assert _dispatched_calls(ast.parse(src)) == [(4, "arccos")]
