"""A token bucket per caller: a sustained rate with bursts, answered with ``Retry-After``."""

from __future__ import annotations

import time


class RateLimiter:
    """``rate`` events per second per key, bursts up to ``burst``."""

    def __init__(self, rate: float, burst: float) -> None:
        """Limit each key to ``rate``/s with at most ``burst`` at once."""
        self.rate = rate
        self.burst = burst
        self._buckets: dict[str, tuple[float, float]] = {}

    def acquire(self, key: str, now: float | None = None) -> float:
        """Take one token for ``key``: 0.0 when allowed, else the seconds until one is free."""
        now = time.monotonic() if now is None else now
        tokens, last = self._buckets.get(key, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate)
        if tokens >= 1.0:
            self._buckets[key] = (tokens - 1.0, now)
            return 0.0
        self._buckets[key] = (tokens, now)
        return (1.0 - tokens) / self.rate
