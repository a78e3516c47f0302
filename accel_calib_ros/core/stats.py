"""
Order statistics without numpy's masked arrays: ``median`` and ``quantile``.

``np.median``, ``np.quantile`` and ``np.unique`` ask ``np.ma`` whether their input is
masked, which imports ``numpy.ma`` (about 10 ms, an eighth of what ``accel-calib fit`` may
spend beyond importing numpy). These give the same numbers ('linear' quantile: the mean
of the two middle values for an even count) from ``np.partition``; NaN propagates as
with numpy.
"""

import math

import numpy as np


def quantile(values, q, axis=None):
    """
    Return the ``q`` quantile of ``values`` (linear interpolation, as ``np.quantile``).

    :param values: array-like.
    :param q: one quantile, 0 <= q <= 1 (0.5: the median).
    :param axis: None (all values) or the axis along which to take it.
    :return: a float for ``axis=None`` (NaN when empty or any value is NaN), else an array.
    """
    a = np.asarray(values, float)
    if axis is None:
        a, axis = a.reshape(-1), 0
    a = np.moveaxis(a, axis, -1)
    n = a.shape[-1]
    if n == 0:
        out = np.full(a.shape[:-1], np.nan)
    else:
        pos = q * (n - 1)
        lo = int(math.floor(pos))
        hi = min(lo + 1, n - 1)
        part = np.partition(a, [lo, hi] if hi != lo else lo, axis=-1)
        low, high = part[..., lo], part[..., hi]
        out = low + (high - low) * (pos - lo)
        nan = np.isnan(a).any(axis=-1)
        out = np.where(nan, np.nan, out)
    return float(out) if np.ndim(out) == 0 else out


def median(values, axis=None):
    """Return the median of ``values`` (along ``axis``), as ``np.median``."""
    return quantile(values, 0.5, axis)
