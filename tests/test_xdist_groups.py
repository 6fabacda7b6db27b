"""scripts/test.sh runs the suite with `-n 2 --dist loadgroup`: the tests of one `xdist_group` (a module whose tests
share a browser tab or a service stack in order) must run on one worker, in order (tests/xdist_groups.py)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

GROUPED = """
import pytest

pytestmark = pytest.mark.xdist_group("shared-tab")

@pytest.mark.parametrize("i", range(6))
def test_in_order(i):
    pass
"""
FREE = """
import pytest

@pytest.mark.parametrize("i", range(6))
def test_anywhere(i):
    pass
"""


def test_a_group_runs_on_one_worker_in_order(tmp_path: Path) -> None:
    (tmp_path / "test_grouped.py").write_text(GROUPED)
    (tmp_path / "test_free.py").write_text(FREE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "tests.xdist_groups", "-p", "no:cacheprovider", "-n", "2"]
        + ["--dist", "loadgroup", "-v", "-o", "addopts=", str(tmp_path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    ran = re.findall(r"\[(gw\d+)\] .*PASSED (\S+)", run.stdout)
    grouped = [(worker, test) for worker, test in ran if "test_grouped.py" in test]
    assert len(grouped) == 6 and len(ran) == 12, run.stdout
    assert len({worker for worker, _ in grouped}) == 1, f"the group was split: {grouped}"
    assert [t for _, t in grouped] == [f"test_grouped.py::test_in_order[{i}]@shared-tab" for i in range(6)]
