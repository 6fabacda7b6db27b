"""The contract's outputs stay byte-identical on the shipped examples (golden.py; tests/golden/README.md)."""

from __future__ import annotations

import json

import pytest

from .golden import CASES, differences, golden_document, golden_path


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_outputs_equal_the_golden_files(case, tmp_path):
    path = golden_path(case)
    assert path.is_file(), f"{path} is missing: run scripts/regen_golden.py (tests/golden/README.md)"
    expected = json.loads(path.read_text(encoding="utf-8"))
    actual = golden_document(case, tmp_path)
    changed = differences(expected, actual)
    assert not changed, (
        f"{case.name}: the outputs changed ({'; '.join(changed)}). If the change of results is deliberate, run "
        "scripts/regen_golden.py and name the change in the commit (tests/golden/README.md)"
    )
    assert actual == expected
