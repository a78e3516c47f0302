"""
The model the workflow fits: a baseline calibration plus effects, over static windows.

:class:`Conditions` is the session as the fit sees it (one row per window), :class:`Model`
the baseline (``ml``: upper-triangular T and bias; ``gn``: diagonal T and bias) plus a
list of effects from ``effects.EFFECTS``, fitted by least squares to the gravity-norm
residuals divided by each window mean's noise; :class:`Fit` one fitted model.
"""

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from .effects import effect_of, name_of


@dataclass
class Conditions:
    """The session as the fit sees it: one row per static window."""

    readings: np.ndarray        # (N, 3) window means, m/s²
    sigma: np.ndarray           # (N, 3) noise of each window mean, m/s²
    temp: np.ndarray            # (N,) °C minus the session mean (zeros if unknown)
    time: np.ndarray            # (N,) s minus the session mean
    gravity: float
    temp_span: float
    time_span: float

    def subset(self, index):
        """Return the conditions of some windows (centring of temperature and time kept)."""
        return Conditions(self.readings[index], self.sigma[index], self.temp[index],
                          self.time[index], self.gravity, self.temp_span, self.time_span)


class Model:
    """Baseline calibration plus a list of effects, fitted by least squares."""

    def __init__(self, baseline, effects):
        """
        Make the model of a baseline and effects.

        :param baseline: 'ml' or 'gn'.
        :param effects: library names or session-bound Effects (``Effect.bind``).
        """
        self.baseline = baseline
        self.effects = list(effects)
        self.objects = {name_of(e): effect_of(e) for e in self.effects}
        self.n_base = 9 if baseline == 'ml' else 6
        self.sizes = [len(effect_of(e).param_names) for e in self.effects]

    @property
    def n_params(self):
        return self.n_base + sum(self.sizes)

    def split(self, x):
        """Return (T, bias, {effect: params}) from the parameter vector."""
        T = np.zeros((3, 3))
        if self.baseline == 'ml':
            T[np.triu_indices(3)] = x[:6]
            bias = x[6:9]
        else:
            T[np.diag_indices(3)] = x[:3]
            bias = x[3:6]
        params, k = {}, self.n_base
        for entry, size in zip(self.effects, self.sizes):
            params[name_of(entry)] = x[k:k + size]
            k += size
        return T, bias, params

    def index(self, name):
        """Return where effect ``name``'s parameters start in the parameter vector."""
        k = self.n_base
        for entry, size in zip(self.effects, self.sizes):
            if name_of(entry) == name:
                return k
            k += size
        raise KeyError(name)

    def pack_baseline(self, T, bias):
        head = T[np.triu_indices(3)] if self.baseline == 'ml' else np.diag(T)
        return np.concatenate([head, bias])

    def true_accel(self, x, c):
        """Invert the model for each window: return the true specific force (N, 3), m/s²."""
        T, bias, params = self.split(x)
        a = np.linalg.solve(T, (c.readings - bias).T).T
        for _ in range(2):          # the effects are small: two fixed-point passes
            extra = sum((self.objects[n].apply(p, a, c.temp, c.time, c.gravity)
                         for n, p in params.items()), np.zeros_like(a))
            a = np.linalg.solve(T, (c.readings - bias - extra).T).T
        return a

    def residual_parts(self, x, c):
        """
        Return the gravity-norm residuals and their noise, both (N,) m/s².

        The noise is the window mean's reading noise mapped to the true frame and taken
        along the normal a/|a|: sqrt(sum_i ((T^-T n)_i sigma_i)²).
        """
        a = self.true_accel(x, c)
        norm = np.linalg.norm(a, axis=1)
        along = np.linalg.solve(self.split(x)[0].T, (a / norm[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        return norm - c.gravity, s

    def residuals(self, x, c):
        """Return (|a| - g) / noise along a for each window, shape (N,)."""
        rho, s = self.residual_parts(x, c)
        return rho / s

    def predict(self, x, directions, c):
        """Return noise-free readings (N, 3) for unit directions under conditions ``c``."""
        T, bias, params = self.split(x)
        a = c.gravity * directions
        raw = a @ T.T + bias
        for name, p in params.items():
            raw = raw + self.objects[name].apply(p, a, c.temp, c.time, c.gravity)
        return raw

    def fit(self, c, start):
        """
        Fit the model to conditions ``c`` by least squares from ``start``.

        :returns: (parameters, chi², Jacobian of the normalised residuals (N, p)).
        """
        sol = optimize.least_squares(self.residuals, start, args=(c,), x_scale='jac',
                                     method='lm' if len(c.readings) > len(start) else 'trf')
        chi2 = float(np.sum(sol.fun ** 2))
        return sol.x, chi2, sol.jac

    def effect_jacobian(self, x, c, name):
        """
        Return d(normalised residual)/d(params of effect ``name``) at ``x``, shape (N, k).

        ``name``: a library name or a session-bound Effect (a model effect's own binding
        is used when it is in the model).

        Evaluated whether or not the effect is in the model (zero parameters if not):
        the change of |a| per unit parameter is -n^T T^-1 columns, n = a/|a|.
        """
        T = self.split(x)[0]
        a = self.true_accel(x, c)
        norm = np.linalg.norm(a, axis=1)
        along = np.linalg.solve(T.T, (a / norm[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        effect = self.objects.get(name_of(name)) or effect_of(name)
        cols = effect.columns(a, c.temp, c.time, c.gravity)
        return -np.einsum('ni,nik->nk', along, cols) / s[:, None]


@dataclass
class Fit:
    """One fitted model and its agreement with the measurement."""

    effects: list
    x: np.ndarray
    chi2: float
    dof: int
    residuals: np.ndarray
    jac: np.ndarray = None

    @property
    def gap(self):
        return float(np.sqrt(self.chi2 / max(self.dof, 1)))


def conditions_from_windows(windows, gravity, inflation=1.0):
    """
    Build the fit's Conditions from StaticWindows.

    :param windows: StaticWindows.
    :param gravity: local gravity, m/s².
    :param inflation: variance factor of a window mean over white noise, scalar or (3,).
    """
    noise = windows.noise_std
    noise = np.where(noise > 0, noise, np.max(noise) if np.max(noise) > 0 else 1e-3)
    sigma = noise[None, :] * np.sqrt(inflation / windows.count[:, None])
    temp = np.asarray(windows.temp, float)
    has_temp = np.all(np.isfinite(temp))
    temp = temp - temp.mean() if has_temp else np.zeros(len(temp))
    time = windows.t_mid - windows.t_mid.mean()
    return Conditions(windows.mean, sigma, temp, time, gravity,
                      float(np.ptp(temp)) if has_temp else 0.0, float(np.ptp(time)))


def fit_model(baseline, effects, c, start):
    model = Model(baseline, effects)
    x, chi2, jac = model.fit(c, start)
    dof = len(c.readings) - model.n_params
    return model, Fit(list(effects), x, chi2, dof, model.residuals(x, c), jac)


def min_windows(baseline):
    """Return the fewest static windows the check needs for ``baseline`` (dof >= 3)."""
    return Model(baseline, []).n_base + 3


def model_start(baseline, cal):
    """Return the parameter vector of the baseline model from a Calibration."""
    return Model(baseline, []).pack_baseline(cal.T, cal.bias)
