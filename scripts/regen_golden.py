#!/usr/bin/env python
"""Rewrite tests/golden/<case>.json from the current code (tests/golden/README.md says when that is legitimate).

Usage: .venv/bin/python scripts/regen_golden.py [CASE ...]   (default: every case of tests/graspgen/golden.py)
       .venv/bin/python scripts/regen_golden.py --check       (compare only; exit 1 when anything differs)
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.graspgen.golden import CASES, GOLDEN_DIR, differences, golden_document, golden_path  # noqa: E402


def main(argv: list[str]) -> int:
    check = "--check" in argv
    names = [a for a in argv if a != "--check"]
    unknown = sorted(set(names) - {c.name for c in CASES})
    if unknown:
        print(f"unknown cases {', '.join(unknown)}: choose from {', '.join(c.name for c in CASES)}", file=sys.stderr)
        return 2
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    status = 0
    for case in CASES:
        if names and case.name not in names:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            doc = golden_document(case, Path(tmp))
        path = golden_path(case)
        old = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None
        changed = "new" if old is None else "; ".join(differences(old, doc)) or "unchanged"
        if check:
            status |= changed != "unchanged"
        else:
            path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        print(f"{case.name}: {changed}")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
