"""
Temperature-band drift tables (Gui Yi, eq. 4-5), without jumps at band edges.

Within each temperature band the drift of axis i is a quadratic in the measured
acceleration (eq. 4)::

    drift_i = quadratic_i * y_i² + linear_i * y_i + offset_i       (m/s²)

and the corrected reading is ``true = T⁻¹ (raw - bias - drift(raw))`` (eq. 5 in this
package's ``raw = T true + bias`` convention). The paper fits the coefficients
against a turntable; in the field the only reference is gravity, so each band is
fitted by Gauss-Newton so that its static windows, corrected by the reference
calibration plus the band's drift, have the local gravity magnitude.

Beyond the paper: the coefficients are attached to the mean temperature of the
windows that built the band and interpolated linearly between neighbouring bands
(extended linearly to the outer band edges, held constant beyond), so the
correction is continuous in temperature, and the coefficients are fitted
jointly with that same interpolation (each window sees the blend at its own
temperature), so fit and lookup agree; a band with too few windows or a
geometry that cannot separate its nine coefficients is reported and skipped (its
neighbours, or no drift at all, take over).
"""


from dataclasses import dataclass, field

import numpy as np


MIN_WINDOWS_PER_BAND = 12
"""Fewest static windows a band needs for its nine coefficients."""


@dataclass(eq=False)          # arrays: equal only to itself
class ThermalBand:
    """
    Drift coefficients of one temperature band.

    :param low_c: band lower edge, °C (inclusive); ``high_c``: upper edge (exclusive).
    :param temp_c: mean temperature of the band's windows, °C (interpolation node).
    :param quadratic: (3,) 1/(m/s²); ``linear``: (3,) dimensionless; ``offset``: (3,) m/s².
    :param windows: static windows in the band.
    :param status: 'ok', or why the band is not used.
    :param residual_rms: gravity-norm residual of the band's windows after correction, m/s².
    :param gyro_bias: (3,) gyroscope bias measured in the band's windows, rad/s, or None.
    """

    low_c: float
    high_c: float
    temp_c: float
    quadratic: np.ndarray
    linear: np.ndarray
    offset: np.ndarray
    windows: int
    status: str = 'ok'
    residual_rms: float = float('nan')
    gyro_bias: np.ndarray = None

    def to_dict(self):
        """Plain YAML-ready mapping (unknown values as None)."""
        d = {'low_c': float(self.low_c), 'high_c': float(self.high_c),
             'temp_c': float(self.temp_c), 'windows': int(self.windows),
             'status': self.status,
             'residual_rms_m_s2': (float(self.residual_rms)
                                   if np.isfinite(self.residual_rms) else None),
             'quadratic_per_m_s2': [float(v) for v in self.quadratic],
             'linear': [float(v) for v in self.linear],
             'offset_m_s2': [float(v) for v in self.offset]}
        if self.gyro_bias is not None:
            d['gyro_bias_rad_s'] = [float(v) for v in self.gyro_bias]
        return d

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict` (no validation: see dataio.calibration_file)."""
        rms = d.get('residual_rms_m_s2')
        gyro = d.get('gyro_bias_rad_s')
        return cls(float(d['low_c']), float(d['high_c']), float(d['temp_c']),
                   np.asarray(d['quadratic_per_m_s2'], float), np.asarray(d['linear'], float),
                   np.asarray(d['offset_m_s2'], float), int(d['windows']), str(d['status']),
                   float('nan') if rms is None else float(rms),
                   None if gyro is None else np.asarray(gyro, float).reshape(3))


@dataclass(eq=False)          # arrays: equal only to itself
class ThermalTable:
    """
    Band drift tables and their continuous lookup.

    :param band_width_c: band width, °C.
    :param bands: ThermalBand list, ordered by temperature.
    :param extrapolation: beyond the outer band edges the coefficients are 'hold' (held at
        the edge: the multi-pose tables) or 'linear' (the end segments' slopes continued: a
        one-pose fit, whose offsets keep moving with temperature past the data).
    :param reference_c: temperature at which the tables are zero (the reference
        calibration's own), °C, or None (multi-pose tables are absolute).
    :param calibrated_c: (low, high) temperatures the fit saw, °C, or None (then the
        usable bands' edges).
    :param hysteresis: ``thermal_lag.Hysteresis`` (the heating/cooling term), or None.
    :param source: 'poses' (many poses per band, Gui Yi) or 'still' (one still pose
        while the temperature sweeps: offsets only).
    """

    band_width_c: float
    bands: list = field(default_factory=list)
    extrapolation: str = 'hold'
    reference_c: float = None
    calibrated_c: tuple = None
    hysteresis: object = None
    source: str = 'poses'

    @property
    def usable(self):
        """Bands with status 'ok', ordered by temperature."""
        return sorted((b for b in self.bands if b.status == 'ok'), key=lambda b: b.temp_c)

    @property
    def range_c(self):
        """(low, high) temperature range the tables were fitted over, °C, or None."""
        if self.calibrated_c is not None:
            return tuple(self.calibrated_c)
        ok = self.usable
        return (ok[0].low_c, ok[-1].high_c) if ok else None

    def outside(self, temp, margin_c=0.0):
        """Tell per temperature (N,) whether it lies beyond the fitted range by ``margin_c``."""
        temp = np.atleast_1d(np.asarray(temp, float))
        span = self.range_c
        if span is None:
            return np.zeros(len(temp), bool)
        with np.errstate(invalid='ignore'):
            return (temp < span[0] - margin_c) | (temp > span[1] + margin_c)

    def coefficients(self, temp):
        """Blended (quadratic, linear, offset), each (N, 3), at temperatures ``temp`` (N,)."""
        temp = np.atleast_1d(np.asarray(temp, dtype=float))
        ok = self.usable
        if not ok:
            z = np.zeros((len(temp), 3))
            return z, z.copy(), z.copy()
        phi = _basis(temp, np.array([b.temp_c for b in ok]), ok[0].low_c, ok[-1].high_c,
                     self.extrapolation)
        return tuple(phi @ np.array([getattr(b, name) for b in ok])
                     for name in ('quadratic', 'linear', 'offset'))

    def drift(self, raw, temp):
        """Drift to subtract from raw readings (N, 3) at temperatures (N,), m/s²."""
        raw = np.atleast_2d(raw)
        temp = np.broadcast_to(np.asarray(temp, float), (len(raw),))
        quad, lin, off = self.coefficients(np.where(np.isfinite(temp), temp, np.nan))
        drift = quad * raw ** 2 + lin * raw + off
        drift[~np.isfinite(temp)] = 0.0
        return drift

    def gyro_bias(self, temp):
        """
        Gyroscope bias (N, 3) rad/s at temperatures ``temp`` (N,) °C, or None.

        Linear between the temperatures of the bands that measured one, held constant
        beyond them (continued linearly past the outer band edges with ``extrapolation``
        'linear'); NaN rows where the temperature is unknown. None when no band carries a
        gyro bias.
        """
        temp = np.atleast_1d(np.asarray(temp, dtype=float))
        bands = sorted((b for b in self.bands if b.gyro_bias is not None),
                       key=lambda b: b.temp_c)
        if not bands:
            return None
        nodes = np.array([b.temp_c for b in bands])
        values = np.array([b.gyro_bias for b in bands])
        if self.extrapolation == 'linear':
            phi = _basis(temp, nodes, bands[0].low_c, bands[-1].high_c, 'linear')
            out = phi @ values
        else:
            out = np.column_stack([np.interp(np.nan_to_num(temp, nan=nodes[0]), nodes,
                                             values[:, k]) for k in range(3)])
        out[~np.isfinite(temp)] = np.nan
        return out

    def to_dict(self):
        """Plain YAML-ready mapping."""
        d = {'band_width_c': float(self.band_width_c),
             'interpolation': 'linear between band temperatures, extended linearly to the '
             'outer band edges, ' + ('continued linearly beyond' if self.extrapolation
                                     == 'linear' else 'held beyond'),
             'extrapolation': self.extrapolation, 'source': self.source,
             'bands': [b.to_dict() for b in self.bands]}
        if self.reference_c is not None:
            d['reference_c'] = float(self.reference_c)
        if self.calibrated_c is not None:
            d['calibrated_c'] = [float(v) for v in self.calibrated_c]
        if self.hysteresis is not None:
            d['hysteresis'] = self.hysteresis.to_dict()
        return d

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict`."""
        from .thermal_lag import Hysteresis
        hyst = d.get('hysteresis')
        span = d.get('calibrated_c')
        return cls(float(d['band_width_c']), [ThermalBand.from_dict(b) for b in d['bands']],
                   str(d.get('extrapolation', 'hold')),
                   None if d.get('reference_c') is None else float(d['reference_c']),
                   None if span is None else tuple(float(v) for v in span),
                   None if hyst is None else Hysteresis.from_dict(hyst),
                   str(d.get('source', 'poses')))


def _basis(temps, nodes, low, high, extrapolation='hold'):
    """
    Interpolation weights (N, B) of each temperature on the node grid.

    Linear between nodes, extended linearly from the end segments out to the covered
    range [low, high] (the outer band edges), and beyond it held constant
    (``extrapolation`` 'hold') or continued along the end segments ('linear').
    """
    t = np.nan_to_num(temps, nan=nodes[0])
    if extrapolation != 'linear':
        t = np.clip(t, low, high)
    if len(nodes) == 1:
        return np.ones((len(t), 1))
    eye = np.eye(len(nodes))
    phi = np.column_stack([np.interp(t, nodes, eye[j]) for j in range(len(nodes))])
    below, above = t < nodes[0], t > nodes[-1]
    frac = (nodes[0] - t[below]) / (nodes[1] - nodes[0])
    phi[below, 0], phi[below, 1] = 1.0 + frac, -frac
    frac = (t[above] - nodes[-1]) / (nodes[-1] - nodes[-2])
    phi[above, -1], phi[above, -2] = 1.0 + frac, -frac
    return phi


def _distinct(vectors, min_angle_deg=15.0):
    """Count the directions among ``vectors`` (N, 3) at least ``min_angle_deg`` apart."""
    u = np.asarray(vectors, float).reshape(-1, 3)
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    remaining = np.ones(len(u), bool)
    count = 0
    while remaining.any():
        remaining &= u @ u[np.argmax(remaining)] < np.cos(np.radians(min_angle_deg))
        count += 1
    return count


def _fit_nodes(z, w, phi, R, b, iterations=10):
    """
    Fit normalised drift coefficients at every node jointly.

    The drift of window k is ``sum_j phi[k, j] * (L_j z² + M_j z + N_j)`` per axis,
    exactly the interpolation used at run time, and the coefficients make
    ``|R (z - b - drift)| = 1`` in the least-squares sense (Gauss-Newton).

    :returns: (coef (B, 3, 3) rows (L, M, N) per axis, residuals (n,), weakest node or None).
    """
    n, nodes = len(z), phi.shape[1]
    coef = np.zeros((nodes, 3, 3))
    basis = np.stack([z ** 2, z, np.ones_like(z)], axis=2)              # (n, 3 axes, 3)

    def residual(coef):
        local = np.einsum('nj,jik->nik', phi, coef)
        a = (z - b - np.einsum('nik,nik->ni', basis, local)) @ R.T
        norm = np.linalg.norm(a, axis=1)
        return a, norm, norm - 1.0

    for _ in range(iterations):
        a, norm, res = residual(coef)
        g = (a / norm[:, None]) @ R                                       # (n, 3)
        local_jac = -(g[:, :, None] * basis).reshape(n, 9)
        J = (phi[:, :, None] * local_jac[:, None, :]).reshape(n, nodes * 9)
        N = J.T @ (w[:, None] * J)
        scale = np.sqrt(np.maximum(np.diag(N), 1e-300))
        sv = np.linalg.svd(N / np.outer(scale, scale), compute_uv=False)
        if sv[-1] <= 1e-8:
            return coef, res, int(np.argmin(phi.sum(axis=0)))
        step = np.linalg.solve(N, -J.T @ (w * res))
        coef = coef + step.reshape(nodes, 3, 3)
        if np.linalg.norm(step) < 1e-12:
            break
    return coef, residual(coef)[2], None


def fit_thermal_table(readings, temps, T, bias, gravity, weights=None, band_width_c=10.0,
                      min_windows=MIN_WINDOWS_PER_BAND):
    """
    Fit temperature-band drift tables against a reference calibration.

    Windows are grouped into bands of ``band_width_c`` (edges at multiples of it). A
    band with at least ``min_windows`` windows contributes a node at the mean
    temperature of its windows; all node coefficients are fitted jointly with the
    same linear interpolation the lookup uses, so the tables are consistent across
    band edges. Bands that fall short are listed with the reason and no node.

    :param readings: (N, 3) static-window mean raw readings, m/s².
    :param temps: (N,) window temperatures, °C.
    :param T: (3, 3) and ``bias`` (3,) m/s²: the reference calibration.
    :param gravity: local gravity, m/s².
    :param weights: (N,) window weights (default 1).
    :returns: ThermalTable.
    """
    y = np.asarray(readings, float).reshape(-1, 3)
    temps = np.asarray(temps, float).reshape(-1)
    w = np.ones(len(y)) if weights is None else np.asarray(weights, float)
    R = np.linalg.inv(T)
    z, b = y / gravity, np.asarray(bias, float) / gravity
    table = ThermalTable(float(band_width_c))
    finite = np.isfinite(temps)
    if not finite.any():
        return table
    zeros = np.zeros(3)
    index = np.floor(temps / band_width_c)
    bands = []
    for k in np.unique(index[finite]):
        sel = finite & (index == k)
        bands.append(ThermalBand(k * band_width_c, (k + 1) * band_width_c,
                                 float(np.average(temps[sel], weights=w[sel])),
                                 zeros, zeros, zeros, int(sel.sum())))
    for band in bands:
        if band.windows < min_windows:
            band.status = (f'too few windows: {band.windows} static windows in '
                           f'{band.low_c:g}..{band.high_c:g} °C, needs {min_windows}')
    zf, wf, tf = z[finite], w[finite] / np.mean(w[finite]), temps[finite]
    while True:
        ok = [band for band in bands if band.status == 'ok']
        if not ok:
            break
        phi = _basis(tf, np.array([band.temp_c for band in ok]), ok[0].low_c, ok[-1].high_c)
        coef, res, weak = _fit_nodes(zf, wf, phi, R, b)
        if weak is None:
            for j, band in enumerate(ok):
                band.quadratic = coef[j, :, 0] / gravity
                band.linear = coef[j, :, 1]
                band.offset = coef[j, :, 2] * gravity
                mine = (tf >= band.low_c) & (tf < band.high_c)
                band.residual_rms = float(np.sqrt(np.mean(res[mine] ** 2))) * gravity
            break
        band = ok[weak]
        mine = (tf >= band.low_c) & (tf < band.high_c)
        dirs = _distinct(zf[mine])
        band.status = (f'too few distinct directions: {dirs} among its {band.windows} windows '
                       'cannot separate the drift terms (hold each axis up and down at this '
                       'temperature)')
    table.bands = bands
    return table
