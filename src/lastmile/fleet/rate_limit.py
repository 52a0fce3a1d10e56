"""Per-token rate limits: a token bucket per bearer token, so one client's flood cannot starve the rest.

Each token may send ``burst`` requests at once and ``rate_per_s`` on average; beyond that it gets 429
with ``Retry-After`` (whole seconds, rounded up, as RFC 9110 requires) until its bucket refills. The
check runs after authentication, so an unknown token never gets a bucket (it gets 401) and the number
of buckets is bounded by the tokens issued.

Defaults, by role: a rider's app polls its ride about once a second and asks for a ride now and
then, so 20 requests/s with bursts of 60 is an order of magnitude above what it needs, while a script
holding a rider token could otherwise send thousands a second over loopback. Operators' dashboards,
shuttles and crossing cameras are the service's own machines and staff: 200/s with bursts of 400, a
ceiling against a stolen or runaway token rather than a budget.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from typing import Any

from fastapi import HTTPException, status

from lastmile.fleet.auth import Principal
from lastmile.fleet.request_guard import BodyRejectedError


@dataclass(frozen=True, slots=True, kw_only=True)
class RateLimit:
    """Attributes:
    rate_per_s: sustained requests per second per token (0 turns limiting off).
    burst: requests a token may send at once after being idle.
    """

    rate_per_s: float
    burst: int


RIDER_LIMIT = RateLimit(rate_per_s=20.0, burst=60)
STAFF_LIMIT = RateLimit(rate_per_s=200.0, burst=400)


def default_limits() -> dict[str, RateLimit]:
    """Role -> limit of each of its tokens."""
    return {
        "rider": RIDER_LIMIT,
        "operator": STAFF_LIMIT,
        "vehicle": STAFF_LIMIT,
        "infrastructure": STAFF_LIMIT,
    }


class TokenBuckets:
    """One bucket per token (by its SHA-256). Not thread-safe: used on the event loop only."""

    def __init__(self, limits: Mapping[str, RateLimit]) -> None:
        self.limits = dict(limits)
        self._buckets: dict[str, tuple[float, float]] = {}  # token sha -> (requests left, when counted)
        self.refused = 0

    def check(self, principal: Principal, now_s: float | None = None) -> None:
        """Take one request from the bucket of ``principal``'s token.

        Raises:
            HTTPException: 429 with ``Retry-After`` when the bucket is empty.
        """
        limit = self.limits.get(principal.role)
        if limit is None or limit.rate_per_s <= 0:
            return
        now = time.monotonic() if now_s is None else now_s
        left, then = self._buckets.get(principal.token_sha, (float(limit.burst), now))
        left = min(float(limit.burst), left + (now - then) * limit.rate_per_s)
        if left < 1.0:
            self._buckets[principal.token_sha] = (left, now)
            self.refused += 1
            wait_s = (1.0 - left) / limit.rate_per_s
            raise HTTPException(
                status.HTTP_429_TOO_MANY_REQUESTS,
                f"rate limit: expected at most {limit.rate_per_s:g} requests/s per {principal.role} token "
                f"(bursts of {limit.burst}), got more; retry in {wait_s:.2f} s",
                headers={"Retry-After": str(max(1, math.ceil(wait_s)))},
            )
        self._buckets[principal.token_sha] = (left - 1.0, now)


def charge_token(scope: MutableMapping[str, Any]) -> None:
    """The request guard's admission: take one request from the bucket of the caller's bearer token
    before its body is read, so a flood from one token (valid requests, 20 MB bodies or NaNs alike)
    is refused at the door. No token or an unknown one is left to the route (401). Uses the app's
    ``state.dispatcher.tokens`` (absent until start-up is done) and ``state.buckets``.

    Raises:
        BodyRejectedError: 429 with ``Retry-After``.
    """
    state = scope["app"].state
    dispatcher = getattr(state, "dispatcher", None)
    if dispatcher is None:
        return
    header = next((v for k, v in scope["headers"] if k == b"authorization"), None)
    if header is None:
        return
    scheme, _, token = header.decode("latin-1").partition(" ")
    principal = dispatcher.tokens.lookup(token.strip()) if scheme.lower() == "bearer" else None
    if principal is None:
        return
    try:
        state.buckets.check(principal)
    except HTTPException as exc:
        raise BodyRejectedError(exc.status_code, str(exc.detail), dict(exc.headers or {})) from None
