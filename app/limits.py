"""Request throttling: token buckets per client address, and the login throttle of the teacher password.

A :class:`RateLimiter` allows ``burst`` requests at once and ``rate`` per second on average for each key
(the client's address); :meth:`RateLimiter.take` says how many seconds to wait when the bucket is empty, which
the API sends back as ``429`` with ``Retry-After``. :class:`LoginThrottle` reserves a token *before* a password
is hashed (so parallel guesses cannot all start an scrypt at once) and gives it back when the password was right:
only wrong guesses use up the allowance, per client and for the whole server.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict

MAX_KEYS = 10_000
"""Buckets kept at most (the least recently used are dropped; a dropped bucket is full again)."""


class RateLimiter:
    """Token buckets keyed by client: ``burst`` tokens, refilled at ``rate`` tokens per second."""

    def __init__(self, rate: float, burst: int, clock=time.monotonic) -> None:
        if rate <= 0 or burst < 1:
            raise ValueError(f"rate limit: need rate > 0 and burst >= 1 (got {rate}, {burst})")
        self.rate = float(rate)
        self.burst = int(burst)
        self._clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, time)
        self._lock = threading.Lock()

    def _tokens(self, key: str, now: float) -> float:
        tokens, then = self._buckets.get(key, (float(self.burst), now))
        return min(float(self.burst), tokens + (now - then) * self.rate)

    def take(self, key: str) -> float | None:
        """Use one token of ``key``: ``None`` when there was one, else the seconds until one is available."""
        with self._lock:
            now = self._clock()
            tokens = self._tokens(key, now)
            if tokens < 1.0:
                self._buckets[key] = (tokens, now)
                self._buckets.move_to_end(key)
                return (1.0 - tokens) / self.rate
            self._buckets[key] = (tokens - 1.0, now)
            self._buckets.move_to_end(key)
            while len(self._buckets) > MAX_KEYS:
                self._buckets.popitem(last=False)
            return None

    def give_back(self, key: str) -> None:
        """Return a token taken by :meth:`take` (the request did not count against the limit)."""
        with self._lock:
            now = self._clock()
            if key in self._buckets:
                self._buckets[key] = (min(float(self.burst), self._tokens(key, now) + 1.0), now)


def retry_after(seconds: float) -> str:
    """The ``Retry-After`` header value: whole seconds, at least 1."""
    return str(max(1, math.ceil(seconds)))


class LoginThrottle:
    """Wrong-password allowance per client and for the whole server (see the module docstring)."""

    def __init__(self, per_client: RateLimiter, overall: RateLimiter) -> None:
        self.per_client = per_client
        self.overall = overall

    def reserve(self, client: str) -> float | None:
        """Take a guess token for ``client``: ``None`` if allowed, else seconds to wait (nothing is taken then)."""
        wait = self.per_client.take(client)
        if wait is not None:
            return wait
        wait = self.overall.take("*")
        if wait is not None:
            self.per_client.give_back(client)
            return wait
        return None

    def succeeded(self, client: str) -> None:
        """The reserved guess was right: it does not count."""
        self.per_client.give_back(client)
        self.overall.give_back("*")


class Limits:
    """The server's limiters, from :class:`app.settings.Settings` (``api_rate``, ``learner_rate``, ``login_*``)."""

    def __init__(self, settings) -> None:
        s = settings
        self.api = RateLimiter(s.api_rate, s.api_burst)
        self.learner = RateLimiter(s.learner_rate, s.learner_burst)
        self.login = LoginThrottle(
            RateLimiter(1.0 / s.login_refill_s, s.login_burst),
            RateLimiter(1.0 / s.login_refill_s * 5, s.login_burst * 5),
        )
