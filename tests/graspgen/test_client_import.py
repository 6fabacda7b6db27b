"""`import graspgen` needs no HTTP library: the client is imported only as `graspgen.client`."""

from __future__ import annotations

import subprocess
import sys


def test_import_graspgen_does_not_import_httpx():
    code = (
        "import sys, graspgen; graspgen.pick\n"
        "assert 'httpx' not in sys.modules and 'graspgen.client' not in sys.modules, sorted(sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
