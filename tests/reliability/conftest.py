"""The shared service fixtures (tests/services_conftest.py, loaded by tests/conftest.py)."""

from services_conftest import *  # noqa: F403
