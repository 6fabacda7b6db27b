"""Loads the shared service fixtures (tests/services_conftest.py) without putting tests/ on sys.path, where
tests/graspgen/ would shadow the graspgen package."""

import importlib.util
import sys
from pathlib import Path

if "services_conftest" not in sys.modules:
    _spec = importlib.util.spec_from_file_location(
        "services_conftest", Path(__file__).resolve().parents[1] / "services_conftest.py"
    )
    _module = importlib.util.module_from_spec(_spec)
    sys.modules["services_conftest"] = _module
    _spec.loader.exec_module(_module)

from services_conftest import *  # noqa: E402,F403
