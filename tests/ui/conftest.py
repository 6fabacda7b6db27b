"""The review page's tests: a real `graspgen serve` and Debian's Chromium driven by Playwright (tests/ui/browser.py)."""

from services_conftest import *  # noqa: F403
