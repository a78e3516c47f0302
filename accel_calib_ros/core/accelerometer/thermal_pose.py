"""
The thermal fit of one still pose: offsets (and the gyro bias) against temperature.

One pose cannot separate a change of scale from a change of offset (each axis reads one
value of gravity), so the fit learns per axis the offset against the reported temperature,
as flight stacks do (PX4's thermal calibration, ArduPilot's INS_TCAL), with the band tables
of the multi-pose fit as its shape: nodes at the mean temperature of each band's bins,
linear between them, continued linearly beyond (``ThermalTable`` with ``source`` 'still').
Per axis i and bin k of pose p::

    mean_ki = c_pi + sum_j beta_ji (phi_j(θ_k) - phi_j(θ_ref)) [+ h_i g_k]

``c_pi`` the pose's constant (what gravity and the reference calibration's bias give
there), ``phi`` the interpolation weights of the nodes, ``θ_ref`` the reference
calibration's own temperature, so that its correction there is unchanged (the tables are
zero at θ_ref), and ``g_k`` the heating/cooling gradient θ - θ_lag of a hysteresis term
(``thermal_lag.Hysteresis``) when one is fitted. The fit is linear least squares per axis,
weighted by the samples per bin. The gyroscope's bias is fitted the same way (without a
hysteresis term) and referenced to the calibration's own gyro bias at θ_ref.

What it knows: the uncertainty of the offset at each temperature (the parameters'
covariance, with the residual scatter as the noise, inflated for its correlation from bin
to bin) and the misfit the bins themselves show near that temperature; with heating and
cooling in the same recording, also the error of each leg predicted from the other.
"""

from dataclasses import dataclass, field

import numpy as np

from .thermal import _basis, ThermalBand, ThermalTable
from .thermal_lag import Hysteresis, LAG_GAP_S, lagged_temperature

MIN_BINS_PER_BAND = 3
"""A band needs at least this many bins for a node."""

HYSTERESIS_T = 5.0
"""A hysteresis coefficient is kept on an axis only beyond this many standard errors."""

LEG_RATE_C_MIN = 0.3
"""A bin heats or cools when its temperature changes faster than this, °C/min."""


@dataclass
class StillFit:
    """
    The outcome of the one-pose thermal fit (see the module docstring).

    :param table: ThermalTable (offsets, gyro biases, reference, range, hysteresis).
    :param residuals: (N, 3) bin means minus the fitted model, m/s².
    :param noise: (3,) noise of a bin mean the fit found (its residual scatter), m/s².
    :param inflation: (3,) variance factor for the residuals' correlation between bins.
    :param accuracy: list of dicts per temperature: temp_c, offset_se_m_s2 (3),
        misfit_m_s2 (3), predicted_accuracy_m_s2 (vector RMS of both).
    :param legs: dict heating/cooling -> bins, and 'held_out' (per axis RMS of each leg
        predicted from the other, m/s²) when both are there.
    :param hysteresis_se: (3,) standard errors of the hysteresis coefficients, or None.
    """

    table: ThermalTable
    residuals: np.ndarray
    noise: np.ndarray
    inflation: np.ndarray
    accuracy: list = field(default_factory=list)
    legs: dict = field(default_factory=dict)
    hysteresis_se: np.ndarray = None

    def predicted_accuracy(self, temp):
        """Return the predicted accuracy (m/s², vector RMS) at ``temp`` °C, None outside."""
        if not self.accuracy:
            return None
        temps = np.array([a['temp_c'] for a in self.accuracy])
        low, high = self.table.range_c
        if not low <= temp <= high:
            return None
        values = np.array([a['predicted_accuracy_m_s2'] for a in self.accuracy])
        return float(np.interp(temp, temps, values))


def _nodes(temp, weight, band_width):
    """
    Return the bands (low, high, node temperature, bins) over the bins' temperatures.

    Edges at multiples of the band width, narrowed so that at least two bands have bins
    enough (a span shorter than two bands still gets a slope); a band with fewer than
    ``MIN_BINS_PER_BAND`` bins joins its neighbour.
    """
    span = float(np.ptp(temp))
    width = float(band_width)
    if span < 2.0 * width:
        width = max(span / 2.0, 1e-3)
    index = np.floor((temp - temp.min()) / width + 1e-9).astype(int) if width != band_width \
        else np.floor(temp / width).astype(int)
    low0 = float(temp.min()) if width != band_width else 0.0
    bands = []
    for k in np.unique(index):
        sel = index == k
        bands.append([low0 + k * width, low0 + (k + 1) * width, sel])
    merged = []
    for band in bands:
        if merged and merged[-1][2].sum() < MIN_BINS_PER_BAND:
            prev = merged.pop()
            band = [prev[0], band[1], prev[2] | band[2]]
        merged.append(band)
    if len(merged) > 1 and merged[-1][2].sum() < MIN_BINS_PER_BAND:
        last = merged.pop()
        merged[-1] = [merged[-1][0], last[1], merged[-1][2] | last[2]]
    out = []
    for low, high, sel in merged:
        node = float(np.average(temp[sel], weights=weight[sel]))
        out.append((low, high, node, int(sel.sum())))
    return out


def _legs(time, temp, segment):
    """Return +1 (heating), -1 (cooling) or 0 per bin, from the smoothed rate of change."""
    rate = np.zeros(len(temp))
    for s in np.unique(segment):
        sel = segment == s
        if sel.sum() >= 3:
            rate[sel] = np.gradient(temp[sel], time[sel]) * 60.0
    from scipy.ndimage import uniform_filter1d
    rate = uniform_filter1d(rate, size=min(9, len(rate)), mode='nearest')
    return np.where(rate > LEG_RATE_C_MIN, 1, np.where(rate < -LEG_RATE_C_MIN, -1, 0))


def _correlation_inflation(r):
    """Return the variance factor (1 + rho) / (1 - rho) of residuals r (N,) in time order."""
    if len(r) < 4 or not np.any(r):
        return 1.0
    rho = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.95))
    return (1.0 + rho) / (1.0 - rho)


class StillDesign:
    """
    The linear model of one still recording: pose constants, referenced nodes, hysteresis.

    :param rec: thermal_still.StillRecording. :param reference_c: θ_ref, °C.
    :param band_width_c: band width, °C. :param hysteresis: Hysteresis (tau) or None.
    :param smooth: the curve through the nodes is a cubic spline (continued
        linearly beyond the end nodes) instead of the tables' straight segments: what the
        model-gap workflow fits, so that the bends between nodes of a smooth real curve are
        not taken for an effect; the tables a fit carries interpolate linearly.
    """

    def __init__(self, rec, reference_c, band_width_c, hysteresis=None, smooth=False):
        self.smooth = smooth
        bins = rec.bins
        self.rec, self.reference_c = rec, float(reference_c)
        self.weight = bins.count / np.mean(bins.count)
        self.bands = _nodes(bins.temp, self.weight, band_width_c)
        self.nodes = np.array([b[2] for b in self.bands])
        self.low, self.high = self.bands[0][0], self.bands[-1][1]
        poses = int(rec.pose.max()) + 1
        self.pose_cols = (rec.pose[:, None] == np.arange(poses)[None, :]).astype(float)
        self.node_cols = self.referenced(bins.temp)
        self.hysteresis = hysteresis
        self.gradient = None if hysteresis is None else gradient_of(rec, hysteresis.tau_s)

    def referenced(self, temp):
        """Return the node columns phi(θ) - phi(θ_ref), (N, B)."""
        basis = _spline_basis if self.smooth and len(self.nodes) > 2 else _linear_basis
        return basis(np.atleast_1d(temp), self) - basis(np.array([self.reference_c]), self)

    def matrix(self, with_hysteresis=True):
        """Return the design matrix: pose, node (and gradient) columns, (N, P + B [+ 1])."""
        cols = [self.pose_cols, self.node_cols]
        if with_hysteresis and self.gradient is not None:
            cols.append(self.gradient[:, None])
        return np.hstack(cols)

    def solve(self, y, rows=None, with_hysteresis=True):
        """Return the weighted least-squares coefficients (p,) of the bins ``y`` over ``rows``."""
        X = self.matrix(with_hysteresis)
        w = np.sqrt(self.weight)
        if rows is not None:
            X, y, w = X[rows], y[rows], w[rows]
        keep = np.any(X != 0, axis=0)
        coef = np.zeros(X.shape[1])
        coef[keep] = np.linalg.lstsq(X[:, keep] * w[:, None], y * w, rcond=None)[0]
        return coef


def _linear_basis(temp, design):
    """Return the tables' interpolation weights of temperatures (N,) on the nodes, (N, B)."""
    return _basis(temp, design.nodes, design.low, design.high, 'linear')


def _spline_basis(temp, design):
    """
    Return a cubic spline's weights of temperatures (N,) on the nodes, (N, B).

    Column j is the spline (not-a-knot ends: a cubic between the last nodes is followed
    exactly) through the j-th unit vector at the nodes; beyond the end nodes it continues
    along its end tangent.
    """
    from scipy.interpolate import CubicSpline
    nodes = design.nodes
    t = np.asarray(temp, float)
    spline = CubicSpline(nodes, np.eye(len(nodes)), bc_type='not-a-knot')
    inside = np.clip(t, nodes[0], nodes[-1])
    out = spline(inside)
    slope = spline(np.array([nodes[0], nodes[-1]]), 1)
    out += np.where(t < nodes[0], t - nodes[0], 0.0)[:, None] * slope[0][None, :]
    out += np.where(t > nodes[-1], t - nodes[-1], 0.0)[:, None] * slope[1][None, :]
    return out


def gradient_of(rec, tau_s):
    """Return the heating/cooling gradient θ - θ_lag per bin of a still recording, °C."""
    bins = rec.bins
    return bins.temp - lagged_temperature(bins.t_mid, bins.temp, tau_s,
                                          gap_s=max(LAG_GAP_S, 1.5 * np.median(np.diff(
                                              bins.t_mid)) if len(bins.t_mid) > 1 else LAG_GAP_S))


def hysteresis_tau(rec, reference_c, band_width_c, grid=12):
    """
    Return the time constant of the gradient form that fits a still recording best, s.

    The residual sum of squares of the linear fit with the gradient column, summed over the
    axes (each weighted by its scatter without it), over time constants from twice the
    bins' spacing (at least 5 s) to a quarter of the recording (at most 30 min), then
    refined between the best one's neighbours.
    """
    from scipy import optimize
    t = rec.bins.t_mid
    spacing = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    low = max(2.0 * spacing, 5.0)
    taus = np.geomspace(low, max(min(0.25 * float(np.ptp(t)), 1800.0), 2.0 * low), grid)
    y = rec.bins.mean
    plain = StillDesign(rec, reference_c, band_width_c)
    scale = np.array([np.std(y[:, i] - plain.matrix(False) @ plain.solve(y[:, i], None, False))
                      for i in range(3)])
    scale = np.where(scale > 0, scale, 1.0)

    def cost(log_tau):
        design = StillDesign(rec, reference_c, band_width_c, Hysteresis(np.exp(log_tau)))
        X = design.matrix()
        return sum(float(np.sum(design.weight * (y[:, i] - X @ design.solve(y[:, i])) ** 2))
                   / scale[i] ** 2 for i in range(3))
    costs = [cost(np.log(tau)) for tau in taus]
    k = int(np.argmin(costs))
    low, high = np.log(taus[max(k - 1, 0)]), np.log(taus[min(k + 1, len(taus) - 1)])
    found = optimize.minimize_scalar(cost, bounds=(low, high), method='bounded',
                                     options={'xatol': 0.005})
    return float(np.exp(found.x)) if found.fun < costs[k] else float(taus[k])


def fit_still(rec, reference_c, band_width_c=10.0, hysteresis=None, gyro_reference=None):
    """
    Fit offset tables (and gyro bias tables) against temperature to a still recording.

    :param rec: thermal_still.StillRecording.
    :param reference_c: the reference calibration's temperature, °C: the tables are zero
        there.
    :param band_width_c: band width of the nodes, °C.
    :param hysteresis: a Hysteresis whose ``tau_s`` is used (None: the best, found by
        ``hysteresis_tau``; its coefficients are fitted here, and kept only on the axes where
        they exceed ``HYSTERESIS_T`` standard errors), or None for no hysteresis term.
    :param gyro_reference: (3,) the reference calibration's gyro bias at ``reference_c``,
        rad/s, or None (the recording's own level is used).
    :returns: StillFit.
    """
    if hysteresis is not None and hysteresis.tau_s is None:
        hysteresis = Hysteresis(hysteresis_tau(rec, reference_c, band_width_c),
                                effect=hysteresis.effect)
    design = StillDesign(rec, reference_c, band_width_c, hysteresis)
    bins = rec.bins
    n_pose, n_node = design.pose_cols.shape[1], len(design.nodes)
    coef = np.zeros((3, design.matrix().shape[1]))
    for i in range(3):
        coef[i] = design.solve(bins.mean[:, i])
    se = None
    if hysteresis is not None:
        se = _hysteresis_se(design, coef)
        weak = np.abs(coef[:, -1]) < HYSTERESIS_T * se
        for i in np.flatnonzero(weak):
            coef[i] = 0.0
            coef[i, :-1] = design.solve(bins.mean[:, i], with_hysteresis=False)
    X = design.matrix()
    fitted = X @ coef.T
    residuals = bins.mean - fitted
    inflation = np.array([_correlation_inflation(residuals[:, i]) for i in range(3)])
    dof = max(len(X) - X.shape[1], 1)
    noise = np.sqrt(np.sum(design.weight[:, None] * residuals ** 2, axis=0) / dof)
    # Node values of the referenced curve: the table's offset at each node.
    at_nodes = design.referenced(design.nodes) @ coef[:, n_pose:n_pose + n_node].T
    gyro = _gyro_nodes(design, gyro_reference)
    zeros = np.zeros(3)
    bands = [ThermalBand(low, high, node, zeros, zeros, at_nodes[j], count, 'ok',
                         float(np.sqrt(np.mean(residuals[_in(bins.temp, low, high)] ** 2)))
                         if _in(bins.temp, low, high).any() else float('nan'),
                         None if gyro is None else gyro[j])
             for j, (low, high, node, count) in enumerate(design.bands)]
    hyst = None
    if hysteresis is not None and np.any(coef[:, -1]):
        hyst = Hysteresis(hysteresis.tau_s, coef[:, -1], hysteresis.effect)
    table = ThermalTable(float(band_width_c), bands, 'linear', float(reference_c),
                         rec.temp_range_c, hyst, 'still')
    out = StillFit(table, residuals, noise, inflation, hysteresis_se=se)
    cov = [_covariance(design, noise[i] ** 2 * inflation[i], i, coef) for i in range(3)]
    out.accuracy = _accuracy(design, cov, residuals, n_pose, n_node)
    out.legs = _held_out_legs(design, rec)
    return out


def _in(temp, low, high):
    return (temp >= low) & (temp < high)


def _covariance(design, variance, axis, coef):
    """Return the covariance of the node coefficients of one axis, (B, B)."""
    X = design.matrix(with_hysteresis=coef[axis, -1] != 0 if design.gradient is not None
                      else False)
    W = design.weight
    keep = np.any(X != 0, axis=0)
    info = (X[:, keep] * W[:, None]).T @ X[:, keep]
    cov = np.zeros((X.shape[1], X.shape[1]))
    cov[np.ix_(keep, keep)] = np.linalg.pinv(info) * variance
    p = design.pose_cols.shape[1]
    return cov[p:p + len(design.nodes), p:p + len(design.nodes)]


def _hysteresis_se(design, coef):
    """Return the standard error of each axis's hysteresis coefficient, (3,)."""
    X = design.matrix()
    W = design.weight
    keep = np.any(X != 0, axis=0)
    inv = np.linalg.pinv((X[:, keep] * W[:, None]).T @ X[:, keep])
    out = np.zeros(3)
    for i in range(3):
        r = design.rec.bins.mean[:, i] - X @ coef[i]
        var = np.sum(W * r ** 2) / max(len(X) - keep.sum(), 1) * _correlation_inflation(r)
        out[i] = np.sqrt(max(inv[-1, -1] * var, 0.0)) if keep[-1] else np.inf
    return out


def _accuracy(design, cov, residuals, n_pose, n_node, step_c=5.0):
    """Return the predicted accuracy at temperatures every ``step_c`` over the fitted range."""
    low, high = design.rec.temp_range_c
    temps = np.unique(np.r_[np.arange(np.ceil(low / step_c) * step_c, high, step_c),
                            low, high])
    phi = design.referenced(temps)
    temp = design.rec.bins.temp
    out = []
    for k, theta in enumerate(temps):
        se = np.sqrt([max(float(phi[k] @ c @ phi[k]), 0.0) for c in cov])
        near = np.abs(temp - theta) <= step_c
        misfit = (np.sqrt(np.mean(residuals[near] ** 2, axis=0)) if near.any()
                  else np.full(3, np.nan))
        total = float(np.sqrt(np.sum(se ** 2) + np.nansum(misfit ** 2)))
        out.append({'temp_c': float(theta), 'offset_se_m_s2': se.tolist(),
                    'misfit_m_s2': np.nan_to_num(misfit).tolist(),
                    'predicted_accuracy_m_s2': total})
    return out


def _gyro_nodes(design, reference):
    """Return the gyro bias at each node (B, 3), referenced to ``reference``, or None."""
    g = design.rec.bins.gyro_mean
    if g is None:
        return None
    coef = np.array([design.solve(g[:, i], with_hysteresis=False) for i in range(3)])
    p = design.pose_cols.shape[1]
    curve = design.referenced(design.nodes) @ coef[:, p:p + len(design.nodes)].T
    if reference is None:
        counts = design.pose_cols.sum(axis=0)
        reference = np.average(coef[:, :p], axis=1, weights=counts)
    return curve + np.asarray(reference, float)[None, :]


def _held_out_legs(design, rec):
    """Fit on heating bins and predict cooling ones, and back: per-axis RMS (m/s²)."""
    legs = _legs(rec.bins.t_mid, rec.bins.temp, rec.segment)
    out = {'heating_bins': int((legs > 0).sum()), 'cooling_bins': int((legs < 0).sum())}
    if out['heating_bins'] < 10 or out['cooling_bins'] < 10:
        return out
    y = rec.bins.mean
    X = design.matrix()
    held = {}
    for name, fit_rows, test_rows in (('heating_to_cooling', legs > 0, legs < 0),
                                      ('cooling_to_heating', legs < 0, legs > 0)):
        pred = np.empty((test_rows.sum(), 3))
        common = design.pose_cols[fit_rows].any(axis=0)
        for i in range(3):
            coef = design.solve(y[:, i], rows=fit_rows)
            pred[:, i] = X[test_rows] @ coef
        r = y[test_rows] - pred
        # Each pose's constant from the fitted leg; a pose only in the other leg: its mean.
        for p in np.flatnonzero(~common):
            sel = design.rec.pose[test_rows] == p
            r[sel] -= r[sel].mean(axis=0)
        held[name] = np.sqrt(np.mean(r ** 2, axis=0)).tolist()
    out['held_out_rms_m_s2'] = held
    return out
