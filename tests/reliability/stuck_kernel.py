"""Installed into one test's worker process only (tests/reliability/worker_stack.py, `shim=True`, calls install()):
importing it changes nothing, so a test may import STUCK_SEED.

A job whose seed is STUCK_SEED behaves like a native kernel that never returns to the interpreter: the soft time
limit's signal (SIGUSR1) stays pending and no progress callback runs, so nothing but the hard time limit (the pool
killing the child process) ends it. Every other job runs the real graspgen.generate.
"""

from __future__ import annotations

import signal
import time

import graspgen

STUCK_SEED = 424242

_generate = graspgen.generate


def generate(*args, **kwargs):  # type: ignore[no-untyped-def]
    params = kwargs.get("params")
    if kwargs.get("seed") == STUCK_SEED or getattr(params, "seed", None) == STUCK_SEED:
        # the Python-level handler of the soft limit never gets to run, as in a kernel that does not return
        signal.signal(signal.SIGUSR1, signal.SIG_IGN)
        while True:
            time.sleep(1)
    return _generate(*args, **kwargs)


def install() -> None:
    """Every later graspgen.generate call goes through `generate` above."""
    graspgen.generate = generate
