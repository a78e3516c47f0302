"""
The moves between static windows: rotations integrated from the rate, clipping, ranges.

A move runs from the end of one static window to the start of the next. Its rotation is
the product of the exact exponentials of every step's rate (``integrate``; for many
moves at once, with the Jacobian the fit needs, :class:`Moves`). A move whose rate
sat on the rail of the gyro's range (``clipped``) cannot be integrated and is dropped.
"""

import numpy as np

from ..errors import InputError
from ..windows import detect_static_windows


CLIP_RUN = 3
"""Consecutive samples at a channel's extreme value that reveal clipping (automatic mode)."""


CLIP_TOLERANCE = 1e-3
"""With a given full scale, a reading within this fraction of it counts as clipped."""


def skew(v):
    """Cross-product matrices (M, 3, 3) of vectors (M, 3)."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _exp_and_jacobian(phi):
    """
    Rotation matrices exp([phi]x) and right Jacobians J_r(phi), each (M, 3, 3).

    ``exp([phi + d]x) = exp([phi]x) exp([J_r(phi) d]x)`` to first order in d.
    """
    th2 = np.sum(phi * phi, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(safe)) / safe ** 2)
    c = np.where(small, 1.0 / 6.0 - th2 / 120.0, (safe - np.sin(safe)) / safe ** 3)
    kx = skew(phi)
    k2 = kx @ kx
    eye = np.eye(3)
    rot = eye + a[:, None, None] * kx + b[:, None, None] * k2
    jac = eye - b[:, None, None] * kx + c[:, None, None] * k2
    return rot, jac


def integrate(rate, t):
    """
    Rotation over a stretch of samples, each rate held until the next sample's time.

    :param rate: (N, 3) body rate, rad/s (calibrated, bias removed).
    :param t: (N,) sample times, s; the rotation runs from ``t[0]`` to ``t[-1]``, so the
        last rate is not used.
    :returns: (3, 3) rotation C from the body frame at ``t[-1]`` to the body frame at
        ``t[0]``: a vector fixed in the world reads ``Cᵀ v0`` at the end if it read
        ``v0`` at the start.
    """
    rate = np.asarray(rate, float).reshape(-1, 3)
    dt = np.diff(np.asarray(t, float).reshape(-1))
    C = np.eye(3)
    if len(dt):
        steps, _ = _exp_and_jacobian(rate[:-1] * dt[:, None])
        for step in steps:
            C = C @ step
    return C


def clipped(gyro, full_scale=None, min_run=CLIP_RUN):
    """
    Find the readings (N, 3) where a raw gyro channel sits at its full-scale limit.

    :param gyro: (N, 3) raw rates (any unit; rad/s in this package).
    :param full_scale: the range in the same unit (e.g. ``np.radians(250)``): a reading
        within ``CLIP_TOLERANCE`` of ± it is clipped. None: find the limit in the data:
        a channel's largest or smallest value is a rail when at least ``min_run``
        consecutive samples sit exactly there (a saturated ADC repeats its extreme
        count; a real peak rarely does), and the smallest such magnitude is taken as
        the full scale of all channels and both signs (one ADC range: a rail touched
        for fewer samples elsewhere, like +32767 twice beside a run at -32768, counts).
    :returns: boolean (N, 3), per channel (``.any(axis=1)`` for the samples).
    """
    g = np.asarray(gyro, float).reshape(-1, 3)
    if full_scale is None:
        rails = []
        for channel in g.T:
            finite = channel[np.isfinite(channel)]
            for rail in ((finite.max(), finite.min()) if len(finite) else ()):
                if rail != 0 and _longest_run(channel == rail) >= min_run:
                    rails.append(abs(rail))
        if not rails:
            return np.zeros(g.shape, bool)
        full_scale = min(rails)
    with np.errstate(invalid='ignore'):
        return np.abs(g) >= abs(full_scale) * (1.0 - CLIP_TOLERANCE)


def _longest_run(mask):
    """Length of the longest run of True in a boolean array."""
    if not mask.any():
        return 0
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))


def _tangent_basis(g):
    """Two unit vectors (M, 2, 3) perpendicular to each unit vector g (M, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(g), axis=1)]
    e1 = np.cross(g, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(g, e1)], axis=1)


class Moves:
    """
    The moves of the fit, padded to a common length (their integration, vectorised).

    :param rate: (M, L, 3) raw rate minus bias, rad/s (zero on padding).
    :param dt: (M, L) step from each sample to the next, s (zero on padding).
    :param g0: (M, 3) unit gravity at the start; ``g1`` at the end; ``basis`` (M, 2, 3).
    """

    def __init__(self, rates, steps, g0, g1):
        m = len(rates)
        length = max((len(r) for r in rates), default=0)
        self.rate = np.zeros((m, length, 3))
        self.dt = np.zeros((m, length))
        for k, (r, d) in enumerate(zip(rates, steps)):
            self.rate[k, :len(r)] = r
            self.dt[k, :len(d)] = d
        self.g0 = np.asarray(g0, float).reshape(-1, 3)
        self.g1 = np.asarray(g1, float).reshape(-1, 3)
        self.basis = _tangent_basis(self.g1)

    def __len__(self):
        return len(self.g0)

    def evaluate(self, K):
        """
        Residuals and Jacobians at correction matrix K.

        :returns: (r (M, 2), J (M, 2, 9) d r / d K row-major, Jb (M, 2, 3) d r / d bias,
            C (M, 3, 3) integrated rotations).
        """
        m, length = self.dt.shape
        rate_dt = self.rate * self.dt[..., None]                     # (M, L, 3)
        step, jac = _exp_and_jacobian((rate_dt @ K.T).reshape(-1, 3))
        step, jac = step.reshape(m, length, 3, 3), jac.reshape(m, length, 3, 3)
        # Every partial product C_i = step_0 ... step_i at once: a prefix scan (log2 L
        # batched products instead of L sequential ones; padding steps are identities).
        prefix, span = step, 1
        while span < length:
            scanned = prefix.copy()
            scanned[:, span:] = prefix[:, :-span] @ prefix[:, span:]
            prefix, span = scanned, 2 * span
        C = prefix[:, -1] if length else np.tile(np.eye(3), (m, 1, 1))
        CJ = prefix @ jac
        A = np.einsum('mlij,mlb->mijb', CJ, rate_dt)   # d epsilon_a / d K_bc (start frame)
        B = np.einsum('mlij,ml->mij', CJ, self.dt)     # sum_i C_i J_r,i dt_i (for the bias)
        predicted = np.einsum('mji,mj->mi', C, self.g0)
        r = np.einsum('mki,mi->mk', self.basis, predicted)
        Q = np.einsum('mki,mij,mja->mka', self.basis, np.transpose(C, (0, 2, 1)),
                      skew(self.g0))
        J = np.einsum('mka,mabc->mkbc', Q, A).reshape(m, 2, 9)
        Jb = -np.einsum('mka,mab,bc->mkc', Q, B, K)
        return r, J, Jb, C

    def angles_deg(self, C):
        """Angle between predicted and measured end directions (M,), and turn (M,), deg."""
        predicted = np.einsum('mji,mj->mi', C, self.g0)
        cross = np.linalg.norm(np.cross(predicted, self.g1), axis=1)
        residual = np.degrees(np.arctan2(cross, np.sum(predicted * self.g1, axis=1)))
        cos_turn = np.clip((np.trace(C, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        return residual, np.degrees(np.arccos(cos_turn))


def portion_means(values, a, b):
    """Mean rows (W, 3) of ``values`` over [a_k, b_k), by cumulative sums."""
    c = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    return (c[b] - c[a]) / np.maximum(b - a, 1)[:, None]


def window_ranges(samples, windows):
    """
    Return the static windows' (start, stop) sample indices, sorted, empty ones left out.

    :param windows: StaticWindows (or anything with ``start``/``stop``), or None to
        detect them in ``samples``.
    :raises InputError: indices outside the recording (windows of another recording).
    """
    if windows is None:
        windows = detect_static_windows(samples)
    start = np.asarray(windows.start, int).reshape(-1)
    stop = np.asarray(windows.stop, int).reshape(-1)
    if len(start) != len(stop) or np.any(start < 0) or np.any(stop > len(samples)):
        raise InputError(f'static windows outside the {len(samples)} samples of the recording')
    keep = stop > start
    order = np.argsort(start[keep])
    return start[keep][order], stop[keep][order]
