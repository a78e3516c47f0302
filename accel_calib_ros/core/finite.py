"""
JSON-safe numbers: nothing non-finite leaves the product.

Every JSON answer (``--json``, the nodes' status and advice topics, service responses)
and every file passes its numbers through here: a float, or None where the value is
unknown or not finite.
"""

import math

import numpy as np


def finite_or_none(value, digits=None):
    """
    Return ``value`` as a float for JSON, None when it is None or not finite.

    :param value: a number (or a numpy scalar), or None.
    :param digits: round to this many decimals; None keeps every digit.
    """
    if value is None:
        return None
    value = float(value)
    if not math.isfinite(value):
        return None
    return value if digits is None else round(value, digits)


def finite_list(array, digits=None):
    """
    Return an array as nested lists of floats (None for a non-finite entry).

    :param array: array-like of any shape, or None (returned as None).
    :param digits: as :func:`finite_or_none`.
    """
    if array is None:
        return None
    a = np.asarray(array, float)
    if a.ndim == 0:
        return finite_or_none(a, digits)
    return [finite_list(v, digits) for v in a]
