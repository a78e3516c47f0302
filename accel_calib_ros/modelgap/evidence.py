"""
How an effect shows in this session: visibility, confounding, size and where.

``visibility`` says whether the poses can show an effect at all, ``column_correlation``
whether two effects look alike here, ``effect_worst_case_mg`` how large an error an
effect makes in corrected acceleration, ``where_variables`` and ``strongest_correlations``
what the residuals follow, ``separation_advice`` what to record to tell two apart.
"""

import numpy as np

from .effect import SEPARATE_BY_POSES
from .effects import effect_of, G0, name_of


def where_variables(c, directions):
    """
    Return the session variables the residuals are compared with, by name.

    Temperature, time, each signed and absolute component n_i of the gravity direction,
    products of two components (a cross-axis term T_ij changes |a| by about
    g n_i n_j T_ij), and temperature and time times each component (an offset that
    moves with temperature changes |a| by n . c (θ - θ̄): it shows against
    temperature × x component, hardly against temperature alone).

    :param c: Conditions.
    :param directions: (N, 3) unit gravity directions of the windows.
    :returns: dict name -> (N,) values.
    """
    out = {'temperature': c.temp, 'time': c.time}
    for i, axis in enumerate('xyz'):
        out[f'{axis} component of gravity'] = directions[:, i]
        out[f'|{axis}| component of gravity'] = np.abs(directions[:, i])
    for i, j in ((0, 1), (0, 2), (1, 2)):
        out[f'{"xyz"[i]} × {"xyz"[j]} component'] = directions[:, i] * directions[:, j]
    for i, axis in enumerate('xyz'):
        out[f'temperature × {axis} component'] = c.temp * directions[:, i]
        out[f'time × {axis} component'] = c.time * directions[:, i]
    return out


def strongest_correlations(residuals, c, directions, top=3):
    """Return the strongest correlations of the residuals, [{'variable', 'r'}], strongest first."""
    out = []
    for name, values in where_variables(c, directions).items():
        if np.ptp(values) > 0 and np.ptp(residuals) > 0:
            r = float(np.corrcoef(residuals, values)[0, 1])
            out.append({'variable': name, 'r': r})
    out.sort(key=lambda d: -round(abs(d['r']), 6))     # ties: the order of the variables
    return out[:top]


def column_correlation(model, fit, c, first, second):
    """
    Return how alike two candidate effects look in this session (0 to 1).

    The largest canonical correlation between the two effects' Jacobian columns after
    removing what the current model already absorbs: 1 when some combination of one
    is indistinguishable from the other (temperature and time rising together).
    """
    base = fit.jac if fit.jac is not None else np.zeros((len(c.readings), 0))
    q_base = np.linalg.qr(base)[0] if base.shape[1] else base

    def basis(name):
        j = model.effect_jacobian(fit.x, c, name)
        if q_base.shape[1]:
            j = j - q_base @ (q_base.T @ j)
        u, s, _ = np.linalg.svd(j, full_matrices=False)
        return u[:, s > 1e-9 * max(s.max(), 1e-300)]

    q1, q2 = basis(first), basis(second)
    if not q1.shape[1] or not q2.shape[1]:
        return 0.0
    return float(min(np.linalg.svd(q1.T @ q2, compute_uv=False).max(), 1.0))


def visibility(model, fit, c, name):
    """
    Return how well this session's poses and conditions can show effect ``name`` (0 to 1).

    For each parameter, the change of the normalised residuals per unit parameter, after
    removing what the current model absorbs, over the change of the raw reading itself
    (the residual only sees a change along gravity). The smallest singular value of
    those scaled columns: 0 when some combination of the effect's parameters is
    invisible, e.g. cross-axis terms with only the six faces, or a quadratic scale
    term that is indistinguishable from the linear one when each axis only sees ±g.
    """
    j = model.effect_jacobian(fit.x, c, name)
    a = model.true_accel(fit.x, c)
    T = model.split(fit.x)[0]
    # The change of the reading per unit parameter in the true frame (T^-1 columns),
    # in units of each window's noise.
    effect = model.objects.get(name_of(name)) or effect_of(name)
    cols = np.einsum('ij,njk->nik', np.linalg.inv(T),
                     effect.columns(a, c.temp, c.time, c.gravity))
    _, s = model.residual_parts(fit.x, c)
    raw = np.linalg.norm(np.linalg.norm(cols, axis=1) / s[:, None], axis=0)
    if fit.jac is not None and fit.jac.shape[1]:
        q = np.linalg.qr(fit.jac)[0]
        j = j - q @ (q.T @ j)
    raw = np.where(raw > 0, raw, np.inf)
    return float(np.linalg.svd(j / raw, compute_uv=False).min())


def fibonacci_directions(n=200):
    """Return ``n`` unit vectors spread evenly over the sphere, shape (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    r = np.sqrt(1.0 - z ** 2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


class WorstGrid:
    """
    The directions and conditions over which an effect's worst case is taken, for one fit.

    The directions of gravity (``directions`` spread over the sphere plus the session's
    own, at most ``session`` of them when given) and the temperatures and times of the
    session (centred as in the fit, so what the baseline absorbs at the session mean is not
    counted; at most ``max_conditions``, the extremes included).
    """

    def __init__(self, model, x, c, max_conditions=60, directions=200, session=None):
        self.T_inv = np.linalg.inv(model.split(x)[0])
        a_session = model.true_accel(x, c)
        if session is not None and len(a_session) > session:
            a_session = a_session[np.linspace(0, len(a_session) - 1, session).round().astype(int)]
        self.dirs = np.vstack([fibonacci_directions(directions),
                               a_session / np.linalg.norm(a_session, axis=1, keepdims=True)])
        conds = np.unique(np.column_stack([c.temp, c.time]), axis=0)
        if len(conds) > max_conditions:
            keep = set(np.linspace(0, len(conds) - 1, max_conditions - 4).round().astype(int))
            keep |= {int(np.argmin(conds[:, 0])), int(np.argmax(conds[:, 0])),
                     int(np.argmin(conds[:, 1])), int(np.argmax(conds[:, 1]))}
            conds = conds[sorted(keep)]
        self.conds, self.gravity = conds, c.gravity

    def rows(self):
        """Return every (direction, temperature, time) of the grid: (D, 3), (D,), (D,)."""
        dirs = np.repeat(self.dirs, len(self.conds), axis=0)
        cond = np.tile(self.conds, (len(self.dirs), 1))
        return dirs, cond[:, 0], cond[:, 1]

    def matrix(self, effect, full=False):
        """
        Return the error per unit parameter of ``effect`` in corrected acceleration, (D, 3, k), mg.

        T^-1 columns(a, θ, t) over the grid. An effect whose columns do not depend on the
        direction (an offset) or on the conditions (a direction term) is evaluated once
        along that axis (``full``: over every row of ``rows`` all the same). The worst case
        of parameters p is max_D |W p| (``worst_case_mg``).
        """
        g, dirs, conds = self.gravity, self.dirs, self.conds
        if full:
            d, temp, time = self.rows()
            cols = effect.columns(g * d, temp, time, g)
            return 1000.0 / G0 * np.einsum('ij,njk->nik', self.T_inv, cols)
        probe = effect.columns(g * dirs[:2], np.full(2, conds[0, 0]), np.full(2, conds[0, 1]),
                               g)
        by_direction = not np.allclose(probe[0], probe[1])
        other = effect.columns(g * dirs[:1], conds[-1:, 0], conds[-1:, 1], g)
        by_condition = not np.allclose(probe[0], other[0])
        dirs = dirs if by_direction else dirs[:1]
        conds = conds if by_condition else conds[:1]
        d = np.repeat(dirs, len(conds), axis=0)
        cond = np.tile(conds, (len(dirs), 1))
        cols = effect.columns(g * d, cond[:, 0], cond[:, 1], g)
        return 1000.0 / G0 * np.einsum('ij,njk->nik', self.T_inv, cols)


def worst_case_matrix(model, x, c, effect, max_conditions=60, directions=200):
    """Return ``WorstGrid(model, x, c, ...).matrix(effect)``, (D, 3, k) mg per unit parameter."""
    return WorstGrid(model, x, c, max_conditions, directions).matrix(effect)


def worst_case_mg(matrix, params):
    """Return max_D |W p| for parameters ``params`` (k,) or (R, k): (R,) or a float, mg."""
    p = np.atleast_2d(np.asarray(params, float))
    err = (matrix.reshape(-1, matrix.shape[-1]) @ p.T).reshape(matrix.shape[0], 3, len(p))
    worst = np.sqrt(np.max(np.sum(err ** 2, axis=1), axis=0))
    return worst if np.ndim(params) > 1 else float(worst[0])


def effect_worst_case_mg(model, x, c, name, params):
    """
    Return the largest error, mg, effect ``name`` with ``params`` makes in corrected acceleration.

    The error T^-1 columns(a, θ, t) p of the corrected specific force, over every
    direction of gravity (200 spread over the sphere plus the session's own) and every
    temperature and time of the session (``worst_case_matrix``).
    """
    effect = model.objects.get(name_of(name)) or effect_of(name)
    return worst_case_mg(worst_case_matrix(model, x, c, effect), params)


def separation_advice(a, b, c):
    """
    Return what to record so that two confounded effects can be told apart.

    What either effect says separates it from the other (``Effect.separation_advice``, by
    their families), else more poses over the sphere.

    :param a: library name or Effect; ``b`` likewise. :param c: the session's Conditions.
    """
    first, second = effect_of(a), effect_of(b)
    return (first.separation_advice(second, c) or second.separation_advice(first, c)
            or SEPARATE_BY_POSES)
