"""A headless Chromium for the review page's tests and benchmark: Debian's /usr/bin/chromium driven by Playwright for
Python (never `playwright install`: no browser is downloaded), software WebGL (SwiftShader)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

CHROMIUM = os.environ.get("GRASPGEN_CHROMIUM", "/usr/bin/chromium")
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
#: screenshots of each step (ignored by git; README, "Tests")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "ui"


def missing() -> str | None:
    """Why the browser cannot run here, or None."""
    if not (Path(CHROMIUM).is_file() or shutil.which(CHROMIUM)):
        return f"Chromium not found at {CHROMIUM} (scripts/setup.sh installs Debian's chromium package)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright (Python) is not installed (pip install -e '.[dev]')"
    return None


def launch(playwright):  # type: ignore[no-untyped-def]
    return playwright.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)


def drawn_share(png: bytes, background: tuple[int, int, int] = (0xF3, 0xF4, 0xF6), tolerance: int = 12) -> float:
    """Share of the pixels of a screenshot that differ from the viewer's background."""
    import io

    import numpy as np
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    return float((np.abs(rgb - np.array(background)).sum(axis=2) > tolerance).mean())


# -- Firefox: Debian's firefox-esr through Marionette (Mozilla's own remote protocol and client) on an Xvfb display
#    (headless Firefox has no GL on a machine without a GPU; on Xvfb it renders WebGL with Mesa's llvmpipe)
FIREFOX = os.environ.get("GRASPGEN_FIREFOX", "/usr/bin/firefox-esr")


def firefox_missing() -> str | None:
    if not Path(FIREFOX).is_file():
        return f"Firefox not found at {FIREFOX} (apt-get install firefox-esr xvfb)"
    if shutil.which("Xvfb") is None:
        return "Xvfb not found (apt-get install xvfb): Firefox needs a display for WebGL here"
    try:
        import marionette_driver  # noqa: F401
    except ImportError:
        return "marionette-driver (Python) is not installed (pip install -e '.[dev]')"
    return None
