"""
The χ² numbers the health test needs, without scipy (the correction node stays lean).

- :func:`chi2_survival`: P(χ²_k > x), exact (the closed forms for even and odd k);
- :func:`chi2_quantile`: the x with P(χ²_k > x) = alpha, by bisection on it (cached: a
  check asks for few distinct k).
"""

from functools import lru_cache
import math


def chi2_survival(x, k):
    """Return P(χ²_k > x) for an integer k >= 1."""
    if k <= 0 or not x > 0:
        return 1.0
    if not math.isfinite(x):
        return 0.0
    half = x / 2.0
    if k % 2 == 0:
        term, total = 1.0, 1.0
        for j in range(1, k // 2):
            term *= half / j
            total += term
        return min(1.0, math.exp(-half) * total)
    root = math.sqrt(x)
    total = math.erfc(root / math.sqrt(2.0))
    term = math.exp(-half) * math.sqrt(2.0 / math.pi) * root     # j = 1: x^(1/2) / 1
    for j in range(1, (k - 1) // 2 + 1):
        total += term
        term *= x / (2 * j + 1)
    return min(1.0, total)


@lru_cache(maxsize=256)
def chi2_quantile(alpha, k):
    """Return x with P(χ²_k > x) = ``alpha`` (0 < alpha < 1, k >= 1)."""
    if k <= 0:
        return 0.0
    lo, hi = 0.0, max(10.0, 4.0 * k)
    while chi2_survival(hi, k) > alpha:
        hi *= 2.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if chi2_survival(mid, k) > alpha:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-10 * hi:
            break
    return hi
