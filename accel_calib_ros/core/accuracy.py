"""
Predicted accuracy of a calibration from its parameter covariance (interface.md §5).

The corrected acceleration is ``a = T⁻¹ (y - b)``. An error ``(dT, db)`` in the
parameters moves it, at a true acceleration ``a0 = g u``, by
``da = -T⁻¹ (dT a0 + db) = J(u) dp`` (first order). Its mean square over the
parameter distribution is ``tr(J(u) C J(u)ᵀ)``; averaged over orientations ``u``
uniform on the sphere (``E[u] = 0``, ``E[u uᵀ] = I/3``) this is ``tr(M C)`` with the
closed-form (9, 9) matrix ``M`` below. Parameters are ordered as
``core.calibration.PARAMETER_NAMES``: T upper triangular row-major, then the bias. numpy only.
"""

import numpy as np

from .constants import G0

_ROWS, _COLS = np.triu_indices(3)


def _check(T, covariance):
    T = np.asarray(T, dtype=float).reshape(3, 3)
    C = np.asarray(covariance, dtype=float).reshape(9, 9)
    return T, 0.5 * (C + C.T)


def _jacobians(R, directions, gravity):
    """d(corrected)/d(params) at true accelerations ``gravity * directions``, (M, 3, 9)."""
    a0 = gravity * np.asarray(directions, dtype=float).reshape(-1, 3)
    J = np.zeros((len(a0), 3, 9))
    for k, (i, j) in enumerate(zip(_ROWS, _COLS)):
        J[:, :, k] = -R[:, i][None, :] * a0[:, j][:, None]
    J[:, :, 6:] = -R
    return J


def sphere_average_matrix(T, gravity=G0):
    """
    (9, 9) matrix ``M`` with ``E_u |da|² = tr(M C)`` for u uniform on the sphere.

    :param T: (3, 3) upper triangular, dimensionless.
    :param gravity: magnitude of the true acceleration, m/s².
    """
    R = np.linalg.inv(np.asarray(T, dtype=float).reshape(3, 3))
    G = R.T @ R
    M = np.zeros((9, 9))
    for k, (i, j) in enumerate(zip(_ROWS, _COLS)):
        for m, (p, q) in enumerate(zip(_ROWS, _COLS)):
            if j == q:
                M[k, m] = gravity ** 2 * G[i, p] / 3.0
    M[6:, 6:] = G
    return M


def predicted_accuracy(T, covariance, gravity=G0):
    """
    RMS error of the corrected acceleration at 1 g over uniform orientations, m/s².

    :param T: (3, 3) fitted T.
    :param covariance: (9, 9) covariance of (T upper row-major, bias), m/s² for the bias.
    :param gravity: local gravity magnitude, m/s².
    :returns: float (NaN when the covariance is not finite).
    """
    T, C = _check(T, covariance)
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(T))):
        return float('nan')
    value = float(np.trace(sphere_average_matrix(T, gravity) @ C))
    return float(np.sqrt(max(value, 0.0)))


def direction_errors(T, covariance, directions, gravity=G0):
    """
    RMS error of the corrected acceleration when gravity lies along each direction.

    :param directions: (M, 3) unit vectors: the true acceleration direction in the
        sensor frame (the axis pointing up reads +1 g).
    :returns: (M,) m/s².
    """
    T, C = _check(T, covariance)
    R = np.linalg.inv(T)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    J = _jacobians(R, u, gravity)
    ms = np.einsum('mik,kl,mil->m', J, C, J)
    return np.sqrt(np.maximum(ms, 0.0))


def norm_errors(T, covariance, directions, gravity=G0):
    """
    RMS error of ``|corrected| - gravity`` when gravity lies along each direction, m/s².

    The part of :func:`direction_errors` along gravity (first order): what a held-out
    static window can measure of a calibration's error (its gravity-norm residual, less
    the window's own noise), so predictions and held-out residuals can be compared.

    :param directions: (M, 3) unit vectors (true gravity direction, sensor frame).
    :returns: (M,) m/s².
    """
    T, C = _check(T, covariance)
    radial = norm_jacobians(T, directions, gravity)
    return np.sqrt(np.maximum(np.einsum('mk,kl,ml->m', radial, C, radial), 0.0))


def norm_jacobians(T, directions, gravity=G0):
    """
    Return the derivative of ``|corrected| - gravity`` by the parameters, (M, 9).

    First order, at the true acceleration ``gravity * direction`` (sensor frame): the rows
    whose covariance :func:`norm_errors` gives (the field monitor's health check uses them
    across orientations).
    """
    T = np.asarray(T, dtype=float).reshape(3, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    J = _jacobians(np.linalg.inv(T), u, gravity)
    return np.einsum('mi,mik->mk', u, J)


FACE_NAMES = ('x axis up', 'x axis down', 'y axis up', 'y axis down', 'z axis up',
              'z axis down')
FACE_DIRECTIONS = np.vstack([np.eye(3)[k // 2] * (1 if k % 2 == 0 else -1) for k in range(6)])


def worst_faces(T, covariance, gravity=G0, limit=None):
    """
    Faces (axis up/down) ordered from the worst predicted error, with their errors.

    :param limit: keep only faces whose error exceeds this, m/s² (None: all).
    :returns: list of (name, unit direction (3,), RMS error m/s²).
    """
    err = direction_errors(T, covariance, FACE_DIRECTIONS, gravity)
    order = np.argsort(-err)
    return [(FACE_NAMES[k], FACE_DIRECTIONS[k], float(err[k])) for k in order
            if limit is None or err[k] > limit]
