"""The per-token rate limit of the API: token buckets in the process, checked by `deps.get_principal` (a 429 problem
with Retry-After when a token is over its rate). `observability.install` sets the limiter up from the settings."""

from __future__ import annotations

import math
import threading
import time

from fastapi import Request

from .problems import ApiError

__all__ = ["TokenBuckets", "check_rate"]


class TokenBuckets:
    """A token bucket per bearer-token name: `rate` requests per second, up to `burst` at once."""

    def __init__(self, rate: float, burst: int) -> None:
        self.rate = rate
        self.burst = float(burst)
        self._buckets: dict[str, tuple[float, float]] = {}  # name -> (tokens, last refill, monotonic)
        self._lock = threading.Lock()

    def take(self, name: str) -> float:
        """0 when the request may go ahead, else the seconds until it would."""
        now = time.monotonic()
        with self._lock:
            tokens, last = self._buckets.get(name, (self.burst, now))
            tokens = min(self.burst, tokens + (now - last) * self.rate)
            if tokens >= 1.0:
                self._buckets[name] = (tokens - 1.0, now)
                return 0.0
            self._buckets[name] = (tokens, now)
            return (1.0 - tokens) / self.rate


def check_rate(request: Request, name: str) -> None:
    """Refuse the request with a 429 problem and Retry-After when the token is over its rate (when limits are on)."""
    limiter: TokenBuckets | None = getattr(request.app.state, "rate_limiter", None)
    if limiter is None:
        return
    wait = limiter.take(name)
    if wait > 0:
        from services.common.metrics import RATE_LIMITED

        RATE_LIMITED.inc()
        raise ApiError(
            429,
            "rate-limited",
            f"this token makes more than {limiter.rate:g} requests per second; retry later",
            title="Too many requests",
            headers={"Retry-After": str(max(1, math.ceil(wait)))},
        )
