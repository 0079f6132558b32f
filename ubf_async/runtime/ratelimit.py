"""One rate limit for the package: a token bucket on whatever clock its caller reads (the
robot clock for the controller's reflex ticks, wall time for the robot's refusal notices)."""

from __future__ import annotations

__all__ = ["TokenBucket"]


class TokenBucket:
    """At most ``burst`` at once and ``rate_hz`` on average, on the clock of the times given to
    :meth:`take`."""

    __slots__ = ("_capacity", "_last_ns", "_tokens", "rate_hz")

    def __init__(self, *, rate_hz: float, burst: int, now_ns: int = 0) -> None:
        if not rate_hz > 0 or burst < 1:
            raise ValueError(f"need rate_hz > 0 and burst ≥ 1, got {rate_hz}, {burst}")
        self.rate_hz = rate_hz
        self._capacity = float(burst)
        self._tokens = float(burst)
        self._last_ns = now_ns

    def take(self, now_ns: int) -> bool:
        """Take one token if there is one."""
        elapsed_s = max(0, now_ns - self._last_ns) / 1e9  # a clock that went back: no refill
        self._last_ns = now_ns
        self._tokens = min(self._capacity, self._tokens + elapsed_s * self.rate_hz)
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False
