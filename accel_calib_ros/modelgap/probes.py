"""
Where the residual lives, without assuming a physical effect.

Smooth nonparametric bases in time, temperature, gravity direction and reading
magnitude, each tested against the residuals by a nested F-test.
"""

import numpy as np
from scipy import stats

from .effects import G0

PROBE_P = 1e-3
"""A nonparametric probe is significant below this F-test p-value."""

ABSORBED = 1e-3
"""A probe direction left with less than this share of its size by the model is absorbed."""


def _cosine_basis(values, degree):
    """
    Return a smooth basis of ``values`` scaled to u in [0, 1].

    cos(k pi u), k = 1..degree (trends, steps, curves), and sin(2 pi k u),
    k = 1..(degree + 1) // 2 (cycles), shape (N, degree + (degree + 1) // 2).
    """
    span = np.ptp(values)
    if span <= 0 or degree < 1:
        return np.zeros((len(values), 0))
    u = (values - values.min()) / span
    cols = [np.cos(np.pi * k * u) for k in range(1, degree + 1)]
    cols += [np.sin(2 * np.pi * k * u) for k in range(1, (degree + 1) // 2 + 1)]
    return np.column_stack(cols)


def _sphere_basis(directions, degree):
    """Return the monomials x^a y^b z^c, 1 <= a+b+c <= degree (spherical harmonics span)."""
    cols = []
    for total in range(1, degree + 1):
        for i in range(total + 1):
            for j in range(total + 1 - i):
                k = total - i - j
                cols.append(directions[:, 0] ** i * directions[:, 1] ** j
                            * directions[:, 2] ** k)
    return np.column_stack(cols)


def delta_bic(chi2, drop, k, n):
    """
    Return the BIC gain of k more terms that lower the chi² ``chi2`` by ``drop`` (n windows).

    The Gaussian BIC with the residual variance estimated, n ln(chi² / (chi² - drop))
    - k ln n: the same as drop - k ln n when the residual is at the noise level, but
    fair while a large disagreement is still unexplained (a flexible set of terms then
    picks up a share of it by chance, which a known-variance BIC would reward).
    """
    rest = max(chi2 - drop, 1e-300 * max(chi2, 1.0))
    return float(n * np.log(max(chi2, 1e-300) / rest) - k * np.log(n))


FAMILY = {'time': 'time', 'temperature': 'temperature', 'direction': 'direction',
          'magnitude': 'direction'}
"""The session variable each probe follows: |y| is a function of the direction at fixed g."""


def probe_bases(model, fit, c):
    """
    Return each probe's orthonormal basis in the noise-normalised residual space.

    Four smooth, nonparametric bases, each after removing what the fitted model can
    already absorb (its Jacobian): a cosine and sine series in time and in temperature
    (alone and times each gravity-direction component, since an offset o(t) moves |a|
    by n . o(t)), low-degree spherical harmonics over the gravity direction, and a cosine
    series in the model's reading magnitude |y|.

    :returns: (normalised residuals (N,), noise s (N,) m/s², dict probe -> (variable
        values, U (N, k) orthonormal)).
    """
    n = len(c.readings)
    rho, s = model.residual_parts(fit.x, c)
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    q = np.linalg.qr(fit.jac)[0] if fit.jac is not None and fit.jac.shape[1] else \
        np.zeros((n, 0))
    # The model's own reading magnitude |y(a)|, not the measured one: the measured |y|
    # carries each window's noise along gravity, which is the residual itself.
    magnitude = np.linalg.norm(model.predict(fit.x, directions, c), axis=1)
    room = max(fit.dof - 3, 0)
    smooth_degree = int(min(6, room // 12))
    sphere_degree = 4 if room >= 40 else 3 if room >= 25 else 2 if room >= 12 else 0

    def offset_and_scale(values):
        # An offset o(v) changes |a| by n . o(v); a scale change by |a| s(v): the smooth
        # times each direction component, and alone.
        basis = _cosine_basis(values, smooth_degree)
        return np.hstack([basis] + [basis * directions[:, [i]] for i in range(3)])

    bases = {
        'time': (c.time, offset_and_scale(c.time)),
        'temperature': (c.temp, offset_and_scale(c.temp)),
        'direction': (directions, _sphere_basis(directions, sphere_degree)
                      if sphere_degree else np.zeros((n, 0))),
        'magnitude': (magnitude, _cosine_basis(magnitude, 3)),
    }
    out = {}
    for name, (values, basis) in bases.items():
        if not basis.shape[1]:
            continue
        basis = basis / s[:, None]          # a smooth in m/s², seen in normalised units
        scale = np.linalg.norm(basis, axis=0).max()
        if q.shape[1]:
            basis = basis - q @ (q.T @ basis)
        u, sv, _ = np.linalg.svd(basis, full_matrices=False)
        # What the model absorbs is only absorbed to first order: the model's columns
        # carry |a| = g + residual, so an absorbed direction leaves a sliver of relative
        # size residual / g that follows the residual itself. Such slivers are not terms.
        u = u[:, sv > ABSORBED * max(scale, 1e-300)]
        if u.shape[1] and fit.dof - u.shape[1] >= 2:
            out[name] = (values, u)
    return rho / s, s, out


def residual_probes(model, fit, c):
    """
    Show where the final residual lives, without assuming a physical effect.

    The smooth bases of ``probe_bases`` are fitted to the noise-normalised residuals; a
    nested F-test gives each its significance. A probe that is significant while no
    library effect is says which variable the missing cause follows.

    :returns: dict probe -> {'p', 'F', 'terms', 'delta_chi2', 'delta_bic', 'rms_mg',
        'max_mg', 'significant', '_x' (per-window variable), '_smooth' (per-window fitted
        values, m/s²), '_basis' (N, k)}.
    """
    r, s, bases = probe_bases(model, fit, c)
    n = len(r)
    out = {}
    for name, (values, u) in bases.items():
        k = u.shape[1]
        proj = u @ (u.T @ r)
        drop = float(proj @ proj)
        rest = max(fit.chi2 - drop, 1e-300)
        F = (drop / k) / (rest / (fit.dof - k))
        p = float(stats.f.sf(F, k, fit.dof - k))
        smooth = proj * s
        out[name] = {'p': p, 'F': float(F), 'terms': int(k), 'delta_chi2': drop,
                     'delta_bic': delta_bic(fit.chi2, drop, k, n),
                     'rms_mg': float(1000.0 * np.sqrt(np.mean(smooth ** 2)) / G0),
                     'max_mg': float(1000.0 * np.max(np.abs(smooth)) / G0),
                     'significant': bool(p < PROBE_P), '_x': values, '_smooth': smooth,
                     '_basis': u}
    return out


def added_on_top(r, chi2, dof, first, second):
    """
    Return the F-test p-value of ``second`` added on top of ``first`` (linearised).

    :param r: (N,) normalised residuals of the current model, chi² ``chi2`` with ``dof``.
    :param first: (N, k1) columns already in (orthogonal to the model's Jacobian).
    :param second: (N, k2) columns added.
    :returns: p-value (1 when ``second`` adds nothing new).
    """
    def span(cols):
        if not cols.shape[1]:
            return cols
        u, sv, _ = np.linalg.svd(cols, full_matrices=False)
        return u[:, sv > ABSORBED * max(sv.max(), 1e-300)]

    # Each block on its own scale first (whitened columns are ~1/noise, bases ~1).
    u1 = span(first)
    u12 = span(np.hstack([u1, span(second)]))
    k = u12.shape[1] - u1.shape[1]
    rest_dof = dof - u12.shape[1]
    if k < 1 or rest_dof < 2:
        return 1.0
    fit1 = float(np.sum((u1.T @ r) ** 2))
    fit12 = float(np.sum((u12.T @ r) ** 2))
    rest = max(chi2 - fit12, 1e-300)
    F = ((fit12 - fit1) / k) / (rest / rest_dof)
    return float(stats.f.sf(F, k, rest_dof))
