"""
The offset's random walk: the one library effect whose terms leave a rough rest.

``BiasRandomWalk`` follows the offset with a trend and a few cosine terms in time. A walk
of K per √s gives each cosine coefficient a variance K² f_k and leaves a wander beyond
the terms (``brownian``), which three things need: the check that a fitted walk is rough
enough to be one (``contradiction``, replayed in the naming simulation by
``replay_veto``), the rest a named walk leaves (``roughness``), and its replicates in the
naming simulation (``simulate_shapes``: Brownian paths). The statistics behind the first
are ``walk_design``, ``walk_rate_low`` and ``walk_smoothness_p``.
"""

import numpy as np

from .effect import Effect, still_time_reason
from ..core.constants import G0


def walk_design(basis, offset_jac, time, start):
    """
    Return what a random walk's rough part does to the residuals of a fit that holds its terms.

    A walk of K_i per √s on axis i has covariance K_i² min(t_a - t0, t_b - t0) between
    windows; seen along gravity and with what the fit absorbs (its Jacobian's span, the
    walk's smooth terms included) projected out, it adds A_i = P (J_i J_iᵀ ∘ M) P per
    unit K_i² to the residual covariance.

    :param basis: (N, p) orthonormal basis of the fit's Jacobian.
    :param offset_jac: (N, 3) change of the normalised residuals per unit offset per axis.
    :param time: (N,) window times, s. :param start: the walk's start, s.
    :returns: (tr A_i (3,), tr A_i A_j (3, 3), residual dof).
    """
    n = len(time)
    p = np.eye(n) - basis @ basis.T
    m = np.minimum.outer(time - start, time - start)
    a = [p @ (np.outer(offset_jac[:, i], offset_jac[:, i]) * m) @ p for i in range(3)]
    traces = np.array([np.trace(x) for x in a])
    cross = np.array([[np.sum(x * y) for y in a] for x in a])
    return traces, cross, float(np.trace(p))


def walk_rate_low(coef, coef_var, factors):
    """
    Return a 99.9 % lower bound of K_i² per axis from a walk's fitted cosine terms, (R, 3).

    A walk of K per √s gives each cosine coefficient a variance K² f_k
    (``BiasRandomWalk.brownian``: about 2 T / (k pi)²): each fitted coefficient, less its
    own estimation variance, over f_k estimates K²; their mean over the 3d terms, times
    3d / chi²_3d(0.999), bounds K² from below.

    :param coef: (R, 3, d) fitted coefficients. :param coef_var: their variances, same shape
        or broadcastable. :param factors: (d,) the f_k.
    """
    from scipy import stats
    from .criterion import P_SUPPORT
    d = coef.shape[-1]
    k2 = np.mean(np.maximum(coef ** 2 - coef_var, 0.0) / factors, axis=-1)
    return k2 * (3 * d) / stats.chi2.ppf(1.0 - P_SUPPORT, 3 * d)


def walk_smoothness_p(chi2, k2, design, nu):
    """
    Return P(chi² this low | the fitted walk is a random walk), (R,).

    The walk's rough part (what its smooth terms cannot follow) adds sum_i K_i² A_i to the
    residual covariance (``walk_design``); chi² then has mean dof + sum K_i² tr A_i and the
    variance of a quadratic form in Gaussians (plus what the noise level's own uncertainty
    adds), matched to a scaled chi² (Satterthwaite). A wander whose terms leave a residual at
    the noise level while its size says it should be rough was not a walk: it followed a
    smooth dependence (another effect's leftovers).
    """
    from scipy import stats
    traces, cross, dof = design
    k2 = np.atleast_2d(k2)
    mean = dof + k2 @ traces
    var = 2.0 * (dof + 2.0 * k2 @ traces + np.einsum('ri,ij,rj->r', k2, cross, k2))
    if np.isfinite(nu):
        var = var + 2.0 * dof ** 2 / max(nu, 1.0)
    scale = var / (2.0 * mean)
    return stats.chi2.cdf(np.asarray(chi2, float) / scale, 2.0 * mean ** 2 / var)


class BiasRandomWalk(Effect):
    name = 'bias_random_walk'
    description = ('the zero-g offset wanders with time (a smooth random walk, not a straight '
                   'line and not with temperature)')
    unit = 'm/s²'
    variable = 'time'
    free_curve = True
    one_pose = True
    nests = ('bias_drift',)
    datasheet_unit = 'g per √s (not in the datasheet)'
    datasheet = 0.1e-3
    sensor_range = (0.05e-3, 0.2e-3)
    sensor_field = 'bias_random_walk'
    on_device = False

    def __init__(self, degree=None, start=0.0, span=1.0):
        self.degree, self.start, self.span = degree, start, span

    @property
    def param_names(self):
        if not self.degree:
            return ()
        return tuple(f'o_{axis}_{j}' for axis in 'xyz' for j in range(self.degree + 1))

    MAX_DEGREE = 4
    """Most cosine terms per axis (beside the trend): with it they hold most of a random
    walk's variance about its mean (its cosine coefficients fall like 1/k); a dependence with
    more structure (a cycle, a step) is left to the time probe and the step alternative."""

    @classmethod
    def degrees_for(cls, windows):
        """Return the numbers of smooth terms per axis to try in a session (2 to 4)."""
        return range(2, int(min(cls.MAX_DEGREE, max(2, (windows - 12) // 6))) + 1)

    def applicable(self, context, baseline):
        span = context.get('time_span', 0.0)
        if span < 60.0:
            return f'the session lasts only {span:.0f} s'
        windows = context.get('windows', 0)
        if windows < 30:
            return f'{windows} windows are too few to follow a wander'
        return still_time_reason(context, baseline)

    def bind(self, c, degree=2):
        return BiasRandomWalk(degree, float(np.min(c.time)), float(max(np.ptp(c.time), 1e-9)))

    def bindings(self, c):
        return [self.bind(c, d) for d in self.degrees_for(len(c.time))]

    def search(self, c, score):
        """Return the binding with the best BIC: a random walk is as rough as the data show."""
        n = len(c.time)
        return max(self.bindings(c), key=lambda b: score(b) - len(b.param_names) * np.log(n))

    def basis(self, time):
        """
        Return the wander's terms over the session, (N, degree + 1).

        u - 1/2 (a walk's trend: its cosine series converges slowly, so the straight part
        is a term of its own, and a plain drift is a special case) and cos(k pi u),
        k = 1..degree, u the time scaled to [0, 1] over the session.
        """
        u = np.clip((np.asarray(time, float) - self.start) / self.span, 0.0, 1.0)
        k = np.arange(1, self.degree + 1)
        return np.column_stack([u - 0.5, np.cos(np.pi * k[None, :] * u[:, None])])

    def columns(self, accel, temp, time, gravity=G0):
        if self.degree is None:
            raise ValueError('bias_random_walk needs a session: use bind(conditions)')
        phi = self.basis(time)
        k = self.degree + 1
        cols = np.zeros((len(time), 3, 3 * k))
        for i in range(3):
            cols[:, i, i * k:(i + 1) * k] = phi
        return cols

    def cosines(self, params):
        """Return the cosine coefficients of parameters (..., 3 (d + 1)) as (..., 3, d)."""
        p = np.asarray(params, float)
        return p.reshape(p.shape[:-1] + (3, self.degree + 1))[..., 1:]

    def brownian(self, time):
        """
        Return what a walk of K = 1 per √s does to these terms at window times ``time``.

        (variance of each cosine coefficient (d,), mean variance per window left beyond all
        the terms and a constant): a Brownian path from the session's start, covariance
        min(t_a, t_b), least-squares fitted by a constant and the terms.
        """
        t = np.asarray(time, float) - self.start
        m = np.minimum.outer(t, t)
        design = np.column_stack([np.ones(len(t)), self.basis(time)])
        a = np.linalg.pinv(design)
        factors = np.einsum('kn,nm,km->k', a, m, a)[2:]
        rest = np.eye(len(t)) - design @ a
        return factors, float(np.trace(rest @ m @ rest.T)) / len(t)

    def wander(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0), points=200):
        """Return the offset wander over the session, (points, 3), in g per axis."""
        phi = self.basis(self.start + self.span * np.linspace(0.0, 1.0, points))
        coef = np.asarray(params, float).reshape(3, self.degree + 1)
        path = phi @ coef.T / np.asarray(sensitivity)
        return (path - path.mean(axis=0)) / gravity

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        path = self.wander(params, gravity, sensitivity)
        rms = np.sqrt(np.mean(path ** 2, axis=0))
        # A random walk of K per sqrt(s) wanders K sqrt(T / 6) RMS about its mean over T.
        k = rms / np.sqrt(self.span / 6.0)
        return ('offset wander ' + ', '.join(
            f'{axis} {1000 * r:.3f} mg RMS' for axis, r in zip('xyz', rms))
            + ' over the session; as a random walk about '
            + ', '.join(f'{1000 * v:.3g}' for v in k) + ' mg/√s')

    def contradiction(self, setfit, measured):
        """
        Return why the walk as fitted is not a random walk, or ''.

        See ``walk_smoothness_p``: too smooth at p < ``criterion.P_SUPPORT``.
        """
        from .criterion import P_SUPPORT
        model, fit, c = setfit.model, setfit.fit, measured.conditions
        walk = model.objects[self.name]
        T, _, params = model.split(fit.x)
        coef = walk.cosines(params[self.name])
        index = model.index(self.name)
        cov = np.linalg.pinv(fit.jac.T @ fit.jac)
        coef_var = walk.cosines(np.diag(cov)[index:index + len(walk.param_names)])
        k2 = walk_rate_low(coef[None], coef_var[None], walk.brownian(c.time)[0])
        a = model.true_accel(fit.x, c)
        along = np.linalg.solve(T.T, (a / np.linalg.norm(a, axis=1)[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        design = walk_design(setfit.basis, -along / s[:, None], c.time, walk.start)
        p = float(walk_smoothness_p([fit.chi2], k2, design, measured.noise_dof)[0])
        if p >= P_SUPPORT:
            return ''
        rate = 1000.0 * np.sqrt(np.max(k2)) / G0 / np.max(np.abs(np.diag(T)))
        expected = design[2] + float((k2 @ design[0])[0])
        return (f'too smooth for a random walk: a walk of at least {rate:.2g} mg/√s (the 99.9 % '
                f'lower bound from its fitted terms) would leave chi² about {expected:.0f} '
                f'beyond its smooth terms, but {fit.chi2:.0f} is left (p = {p:.1e}): its terms '
                'follow a smooth dependence, not a wander')

    def roughness(self, model, x, c):
        """
        Return the variance per window, (m/s²)², that the walk as fitted leaves beyond its terms.

        A random walk of K per √s gives each cosine coefficient a variance K² f_k and leaves
        a wander beyond the terms of variance K² r per window (``brownian``, about
        2 T / (k pi)² and T / (pi² d) over a session of T seconds). K is estimated from the
        fitted coefficients; the wander is taken along gravity, averaged over windows.
        """
        walk = model.objects[self.name]
        T, _, params = model.split(x)
        coef = walk.cosines(params[self.name]) / np.abs(np.diag(T))[:, None]
        factors, rest = walk.brownian(c.time)
        k2 = np.mean(coef ** 2 / factors, axis=1)
        rough = k2 * rest                                          # variance per axis
        a = model.true_accel(x, c)
        n = a / np.linalg.norm(a, axis=1, keepdims=True)
        return float(np.mean(n ** 2 @ rough))

    def simulate_shapes(self, design, rng, count):
        """Return ``count`` Brownian offset paths as residual changes, worst case 1 mg each."""
        t = design.fits.c.time
        order = np.argsort(t, kind='stable')
        dt = np.diff(t[order], prepend=t[order][0])
        steps = rng.standard_normal((count, len(t), 3)) * np.sqrt(dt)[None, :, None]
        path = np.empty_like(steps)
        path[:, order] = np.cumsum(steps, axis=1)
        path -= path.mean(axis=1, keepdims=True)
        worst = np.max(np.linalg.norm(path @ design.T_inv.T, axis=2), axis=1) * 1000.0 / G0
        path /= worst[:, None, None]
        return np.einsum('rni,ni->rn', path[:, design.row_window], design.offset)

    def replay_veto(self, stack, params, chi2, design):
        """Return 'too smooth' for replicates whose fitted walk is not rough enough (above)."""
        from .criterion import P_SUPPORT
        b = stack.options[0]
        walk = b.effect
        k2 = walk_rate_low(walk.cosines(params), walk.cosines(b.coef_var)[None],
                           walk.brownian(design.fits.c.time)[0])
        if 'walk_design' not in b.memo:
            b.memo['walk_design'] = walk_design(b.joint_basis(), design.offset,
                                                design.fits.c.time, walk.start)
        p_walk = walk_smoothness_p(chi2, k2, b.memo['walk_design'], design.noise_dof)
        return np.where(p_walk < P_SUPPORT, 'too smooth', '')

    def to_si(self, value):
        return value * G0
