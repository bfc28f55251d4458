"""The first grid point where a monotone test holds, searched from a guess (a neighbouring problem's
answer): doubling steps away from the guess bracket it, bisection closes the bracket. Two tests where
the answer has not moved, against log2(K) for bisection over the whole grid."""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["first_true"]


def first_true(test: Callable[[int], bool], K: int, *, guess: int | None = None) -> int:
    """The smallest k in 0..K with ``test(k)`` for a test that is false below some k and true from
    there on; K when it holds nowhere below K (K itself is not tested). Without a guess: k = 0 tested
    first, then bisection over the whole grid."""
    if K <= 0:
        return 0
    if guess is None:
        lo, hi = (-1, 0) if test(0) else (0, K)
    else:
        lo, hi = _bracket(test, min(max(int(guess), 0), K - 1), K)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if test(mid):
            hi = mid
        else:
            lo = mid
    return hi


def _bracket(test: Callable[[int], bool], k0: int, K: int) -> tuple[int, int]:
    """(lo, hi): test(hi) (or hi = K) and not test(lo) (or lo = -1), by steps doubling away from k0."""
    if test(k0):
        hi, d = k0, 1
        while hi > 0:
            probe = max(hi - d, 0)
            if not test(probe):
                return probe, hi
            hi, d = probe, 2 * d
        return -1, 0
    lo, d = k0, 1
    while lo + d < K:
        if test(lo + d):
            return lo, lo + d
        lo, d = lo + d, 2 * d
    return lo, K
