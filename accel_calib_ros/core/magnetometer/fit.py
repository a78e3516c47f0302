"""
Magnetometer (AK8963) hard iron, soft iron and alignment to the accelerometer (interface.md §10).

Model, for the local Earth field ``f`` in the body (accelerometer) frame, µT::

    raw = T @ R @ f + hard_iron
    f   = Rᵀ T⁻¹ (raw - hard_iron)                    (:func:`correct_field`)

``T`` (soft iron, dimensionless) is upper triangular with a positive diagonal and
``R`` is the rotation from the accelerometer frame to the magnetometer's. Any product
of a physical soft iron and a misalignment has exactly one such form (an RQ
decomposition, :func:`canonical`): the upper-triangular ``T`` is what the data fix,
``R`` absorbs the rest.

Step 1 (soft and hard iron): every magnetometer sample of the session, moving or
still, lies on the ellipsoid ``|T⁻¹ (raw - hard_iron)| = |f|``. The accelerometer's
maximum-likelihood machinery (``core.ml.fit_ml``, Sun & Xu's Newton iteration) fits it
with radius 1, giving ``T1 = T |f|`` in µT and the hard iron. The field magnitude and
the overall scale of ``T`` are one quantity to the data: by default the magnetometer's
factory sensitivity is trusted on average, ``det T = 1``, so ``field_uT = det(T1)^(1/3)``;
pass a known ``field_uT`` (e.g. from a geomagnetic model) to fix the scale instead.

Step 2 (alignment): in the static windows the angle between gravity (the
accelerometer's up direction, calibrated when a correction is given) and the field is
the same in every pose: ``up · f / |f| = -sin(dip)``. ``R`` (3 parameters) and the dip
are fitted by Gauss-Newton on ``asin(-up · Rᵀ v) - dip`` (``v`` the step-1 corrected
field direction in the magnetometer frame), started from a linear solution when there
are enough windows (the 3x3 matrix ``M = Rᵀ`` and ``c = -sin(dip)`` solve
``upᵀ M v = c`` homogeneously; the nearest rotation to ``M``, a Kabsch/Wahba-style
projection) and from identity (the driver's axis swap), keeping the better.

Covariance: step 1's ML covariance (its noise from the data), step 2's
``sigma² (JᵀJ)⁻¹`` with the residual scatter, and step 1's errors carried into R
through the windows (implicit-function Jacobian). ``predicted_accuracy`` (µT) is the
RMS error of the corrected field over field directions uniform on the sphere, from
that covariance: the error is affine in the direction u, ``J(u) dp = (J0 + sum_j u_j
D_j) dp``, so its mean square over the sphere is ``tr((J0ᵀJ0 + sum_j D_jᵀD_j / 3) C)``
in closed form (the Jacobians by central differences).

Coverage: :func:`sphere_coverage` is the fraction of the sphere of field directions
the samples visited (equal-area cells); below ``min_coverage`` the fit is refused, as
the ellipsoid is then poorly determined, and so it is when the directions stay near
one cone or plane (:data:`MIN_SPREAD`), which a path along one circle can do while it
crosses many cells. numpy/scipy only.
"""

from dataclasses import dataclass, field

import numpy as np

from ..accelerometer.ellipsoid import UPPER
from ..accelerometer.ml import fit_ml
from ..errors import CalibrationError, InputError
from ..gyroscope.fit import accel_corrector
from ..gyroscope.moves import skew, window_ranges

COVERAGE_CELLS = 50
"""Equal-area cells on the sphere for :func:`sphere_coverage` (about 33° across each)."""

MIN_COVERAGE = 0.25
"""
Fraction of the sphere the field directions must visit for the fit.

On simulated sessions (moves along great circles between held poses): 24 random poses
visit 64-87 %, the six faces 38 %, six random poses 24-39 % (field errors of about 1 %
of T); tilts within 60° of one face up visit 16-24 % (T errors of 2 %), within 30°,
8-10 % (the ellipsoid fit degenerates).
"""

MIN_SPREAD = 0.05
"""
Smallest eigenvalue of the mean ``u uᵀ`` of the field directions accepted (1/3 when
they fill the sphere). A sensor turned about one axis only (a robot yawing on the
floor) keeps the field on one cone: 0.02 on a simulated session, although its path
crosses 32 % of the cells; six random poses give 0.05-0.11, the six faces 0.23.
"""

MIN_FIELD_TO_NOISE = 20.0
"""
Smallest ratio of the fitted field magnitude to the per-sample noise accepted.

Samples that never changed direction (a sensor that did not turn, or one stuck reading)
are a blob of noise, to which the ellipsoid fit happily fits a sphere of the noise's
size: 0.9 µT for 0.4 µT noise (ratio 4); a real session gives 48 µT for 0.4 µT (120),
an indoor field of 25 µT with a 0.6 µT noise still 40.
"""

MIN_ALIGNMENT_WINDOWS = 6
"""Static windows with magnetometer samples needed to fit R and the dip (4 unknowns)."""

MAX_ALIGNMENT_STD_DEG = 2.0
"""R whose standard error exceeds this (degrees) is not trusted: it stays identity."""


def coverage_cells(cells=COVERAGE_CELLS):
    """Centres (cells, 3) of the nearly equal-area cells: a Fibonacci lattice, unit vectors."""
    i = np.arange(cells) + 0.5
    z = 1.0 - 2.0 * i / cells
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def visited_cells(directions, cells=COVERAGE_CELLS, min_samples=1):
    """
    Tell which cells of :func:`coverage_cells` a set of directions visits.

    :param directions: (N, 3) vectors (normalised here; zero or non-finite rows ignored).
    :returns: boolean (cells,): at least ``min_samples`` directions fall in the cell (the
        Voronoi cell of its lattice point).
    """
    from scipy.spatial import cKDTree
    d = np.asarray(directions, float).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    if not ok.any():
        return np.zeros(cells, bool)
    d = d[ok] / norm[ok, None]
    _, cell = cKDTree(coverage_cells(cells)).query(d)
    return np.bincount(cell, minlength=cells) >= min_samples


def sphere_coverage(directions, cells=COVERAGE_CELLS, min_samples=1):
    """
    Measure the fraction of the sphere that a set of directions visits.

    The sphere is cut into ``cells`` cells of nearly equal area: the Voronoi cells of a
    Fibonacci lattice (each direction goes to the nearest lattice point). A cell is
    visited when at least ``min_samples`` directions fall in it.

    :param directions: (N, 3) vectors (normalised here; zero or non-finite rows ignored).
    :param cells: number of cells.
    :param min_samples: directions needed for a cell to count.
    :returns: float in [0, 1].
    """
    return float(np.mean(visited_cells(directions, cells, min_samples)))


def canonical(T, R, field_uT, field_known=False):
    """
    Put a soft iron ``T`` (any 3x3) and a misalignment ``R`` in the model's own form.

    ``T @ R = T' @ R'`` with ``T'`` upper triangular (positive diagonal) and ``R'`` a
    rotation (RQ decomposition). Unless ``field_known``, ``T'`` is then scaled to
    ``det T' = 1`` and the field magnitude by the inverse, so that
    ``T' R' f' = T R f`` with ``|f'| = field_uT'``: the convention of
    :func:`fit_magnetometer`.

    :returns: (T' (3, 3), R' (3, 3), field_uT' float).
    :raises InputError: ``T @ R`` is singular or a reflection (the axes are mapped
        wrongly).
    """
    from scipy.linalg import rq
    A = np.asarray(T, float).reshape(3, 3) @ np.asarray(R, float).reshape(3, 3)
    if not np.linalg.det(A) > 0:
        raise InputError('soft iron x misalignment is singular or a reflection: check the '
                         'magnetometer axis mapping (x_mag = y_acc, y_mag = x_acc, '
                         'z_mag = -z_acc)')
    U, Q = rq(A)
    D = np.diag(np.sign(np.diag(U)))
    U, Q = U @ D, D @ Q
    scale = 1.0 if field_known else float(np.linalg.det(U)) ** (1.0 / 3.0)
    return U / scale, Q, float(field_uT) * scale


def correct_field(raw, T, hard_iron_uT, R):
    """
    Field in the body (accelerometer) frame, µT: ``Rᵀ T⁻¹ (raw - hard_iron)``.

    :param raw: (N, 3) raw magnetometer readings, µT (NaN rows stay NaN).
    :returns: (N, 3) µT.
    """
    raw = np.atleast_2d(np.asarray(raw, float))
    return np.linalg.solve(np.asarray(T, float),
                           (raw - np.asarray(hard_iron_uT, float)).T).T @ np.asarray(R, float)


@dataclass
class MagnetometerCalibration:
    """
    Result of :func:`fit_magnetometer` (interface.md §10).

    :param T: (3, 3) soft iron, upper triangular, dimensionless (det 1 unless the field
        magnitude was given).
    :param hard_iron_uT: (3,) µT, magnetometer frame.
    :param R: (3, 3) rotation from the accelerometer frame to the magnetometer's
        (identity when ``alignment_fitted`` is False).
    :param field_uT: local field magnitude, µT.
    :param dip_deg: inclination below the horizontal, degrees (up · f = -sin(dip) |f|).
    :param predicted_accuracy: RMS error of the corrected field over field directions
        uniform on the sphere, µT, from ``covariance``.
    :param coverage: fraction of the sphere of field directions the samples visited.
    :param residual_rms_uT: RMS of |corrected field| - field_uT over the samples, µT.
    :param covariance: (12, 12) covariance of (T x field_uT upper triangular row-major,
        µT; hard_iron_uT, µT; rotation-vector error of R applied on the left, rad).
    :param dip_std_deg: standard error of ``dip_deg``, degrees.
    :param sigma_uT: noise of one magnetometer sample from the fit's scatter, µT.
    :param dip_residual_deg: RMS of the dip-angle residuals over the windows, degrees.
    :param samples_used: magnetometer samples in step 1.
    :param windows_used: static windows in step 2.
    :param alignment_fitted: R was fitted (enough windows, well determined).
    :param converged: both steps converged and R was fitted.
    :param message: a sentence on the outcome.
    """

    T: np.ndarray
    hard_iron_uT: np.ndarray
    R: np.ndarray
    field_uT: float
    dip_deg: float
    predicted_accuracy: float
    coverage: float
    residual_rms_uT: float
    covariance: np.ndarray = field(default_factory=lambda: np.full((12, 12), np.nan))
    dip_std_deg: float = float('nan')
    sigma_uT: float = float('nan')
    dip_residual_deg: float = float('nan')
    samples_used: int = 0
    windows_used: int = 0
    alignment_fitted: bool = False
    converged: bool = False
    message: str = ''

    def correct(self, raw):
        """Return the field (N, 3) µT in the accelerometer frame from raw readings (N, 3)."""
        return correct_field(raw, self.T, self.hard_iron_uT, self.R)


def _unpack(p):
    """Return (T1 (3, 3) upper, hard iron (3,)) from the 9-vector of step 1."""
    T1 = np.zeros((3, 3))
    T1[UPPER] = p[:6]
    return T1, np.asarray(p[6:9], float)


def _field_directions(T1, hard_iron, means):
    """Return unit field directions (W, 3), magnetometer frame, from mean raw readings."""
    v = np.linalg.solve(T1, (means - hard_iron).T).T
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _dip_residuals(R, dip, up, v):
    """Residuals (W,) rad and Jacobian (W, 4) w.r.t. (left rotation vector of R, dip)."""
    s = -np.einsum('ki,ij,kj->k', up, R.T, v)
    s = np.clip(s, -1.0 + 1e-15, 1.0 - 1e-15)
    r = np.arcsin(s) - dip
    ds = -np.einsum('ki,ij,kjl->kl', up, R.T, skew(v))
    J = np.column_stack([ds / np.sqrt(1.0 - s * s)[:, None], -np.ones(len(s))])
    return r, J


def _refine(R, dip, up, v, max_iter=50):
    """Gauss-Newton on (R, dip); returns (R, dip, residuals, Jacobian, converged)."""
    from scipy.spatial.transform import Rotation
    converged = False
    for _ in range(max_iter):
        r, J = _dip_residuals(R, dip, up, v)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        R = Rotation.from_rotvec(step[:3]).as_matrix() @ R
        dip += step[3]
        if np.max(np.abs(step)) < 1e-12:
            converged = True
            break
    r, J = _dip_residuals(R, dip, up, v)
    return R, dip, r, J, converged


def _linear_start(up, v):
    """R and dip from ``upᵀ M v = c`` solved homogeneously, M projected on rotations."""
    A = np.column_stack([np.einsum('ki,kj->kij', up, v).reshape(-1, 9), -np.ones(len(up))])
    x = np.linalg.svd(A)[2][-1]
    M, c = x[:9].reshape(3, 3), x[9]
    if np.linalg.det(M) < 0:
        M, c = -M, -c
    U, S, Wt = np.linalg.svd(M)
    Rt = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Wt))]) @ Wt
    return Rt.T, float(np.arcsin(np.clip(-c / np.mean(S), -1.0, 1.0)))


def fit_alignment(up, v):
    """
    Rotation R (accelerometer to magnetometer frame) and dip from static windows.

    :param up: (W, 3) unit gravity (up) directions, accelerometer frame.
    :param v: (W, 3) unit field directions, magnetometer frame (soft/hard iron removed).
    :returns: (R (3, 3), dip rad, residuals (W,) rad, Jacobian (W, 4), converged).
    """
    starts = [(np.eye(3), float(np.mean(np.arcsin(np.clip(-np.sum(up * v, axis=1), -1, 1)))))]
    if len(up) >= 10:
        starts.append(_linear_start(up, v))
    best = None
    for R0, dip0 in starts:
        try:
            out = _refine(R0, dip0, up, v)
        except np.linalg.LinAlgError:
            continue
        if best is None or np.sum(out[2] ** 2) < np.sum(best[2] ** 2):
            best = out
    if best is None:
        raise CalibrationError('the dip-angle fit of the magnetometer alignment failed')
    return best


def _field_error_matrix(T1, hard_iron, R, field_known, field_uT):
    """
    (12, 12) M with ``E_u |error of the corrected field|² = tr(M C)`` over the sphere.

    Parameters: T1 upper (6), hard iron (3), left rotation vector of R (3). The
    corrected field ``F(T1) Rᵀ T1⁻¹ (raw - h)`` with ``raw = T1 R u + h`` (true) is
    affine in u, so its Jacobian is ``J0 + sum_j u_j D_j`` (central differences).
    """
    from scipy.spatial.transform import Rotation
    p0 = np.concatenate([T1[UPPER], hard_iron, np.zeros(3)])
    A0 = T1 @ R

    def corrected(p, u):
        T, h = _unpack(p[:9])
        Rp = Rotation.from_rotvec(p[9:]).as_matrix() @ R
        scale = field_uT if field_known else np.linalg.det(T) ** (1.0 / 3.0)
        return scale * Rp.T @ np.linalg.solve(T, A0 @ u + hard_iron - h)

    step = np.concatenate([np.full(6, 1e-6 * np.max(np.abs(T1))),
                           np.full(3, 1e-6 * np.max(np.abs(T1))), np.full(3, 1e-6)])
    units = [np.zeros(3)] + list(np.eye(3))
    J = np.zeros((4, 3, 12))
    for k, u in enumerate(units):
        for i in range(12):
            d = np.zeros(12)
            d[i] = step[i]
            J[k, :, i] = (corrected(p0 + d, u) - corrected(p0 - d, u)) / (2 * step[i])
    D = J[1:] - J[0]
    return J[0].T @ J[0] + np.einsum('jai,jak->ik', D, D) / 3.0


def _window_means(samples, windows, correct_accel, mag_ok):
    """Mean up directions (W, 3) and mean raw field (W, 3) of windows with mag samples."""
    start, stop = window_ranges(samples, windows)
    cm = np.vstack([np.zeros((1, 3)), np.cumsum(np.where(mag_ok[:, None], samples.mag, 0.0),
                                                axis=0)])
    cn = np.r_[0, np.cumsum(mag_ok)]
    n_mag = cn[stop] - cn[start]
    keep = n_mag > 0
    start, stop, n_mag = start[keep], stop[keep], n_mag[keep]
    mag = (cm[stop] - cm[start]) / n_mag[:, None]
    ca = np.vstack([np.zeros((1, 3)), np.cumsum(samples.accel, axis=0)])
    accel = (ca[stop] - ca[start]) / (stop - start)[:, None]
    temp = None
    if samples.temp is not None:
        ct = np.r_[0.0, np.cumsum(samples.temp)]
        temp = (ct[stop] - ct[start]) / (stop - start)
    up = correct_accel(accel, temp)
    return up / np.linalg.norm(up, axis=1, keepdims=True), mag


def fit_magnetometer(samples, windows=None, accel=None, field_uT=None,
                     min_coverage=MIN_COVERAGE, min_windows=MIN_ALIGNMENT_WINDOWS):
    """
    Calibrate the magnetometer: soft iron, hard iron, alignment, field and dip (§10).

    :param samples: Samples with ``mag`` (µT, accelerometer frame as the driver maps the
        axes; NaN rows where there is no magnetometer sample).
    :param windows: StaticWindows for the alignment, or None to detect them.
    :param accel: accelerometer correction for the up directions (see
        ``core.gyroscope.fit.fit_gyro``): None, a callable, a Calibration or a (T, bias) pair.
    :param field_uT: known field magnitude, µT, or None to fit it (``det T = 1``).
    :param min_coverage: smallest fraction of the sphere of field directions accepted
        (0 also switches off the test for directions near one cone).
    :param min_windows: static windows with magnetometer samples needed to fit R.
    :returns: MagnetometerCalibration.
    :raises InputError: no magnetometer data, or malformed arguments.
    :raises CalibrationError: too few samples, too little of the sphere covered (the
        message says how much was seen), or a degenerate fit.
    """
    if samples.mag is None:
        raise InputError('no magnetometer data: the recording needs mx my mz columns (µT)')
    if field_uT is not None and not (np.isfinite(field_uT) and field_uT > 0):
        raise InputError(f'field_uT must be a positive number of µT, got {field_uT!r}')
    correct_accel = accel_corrector(accel)
    mag_ok = samples.mag_rows
    mag = samples.mag[mag_ok]
    n = len(mag)
    if n < 10:
        raise CalibrationError(f'{n} magnetometer samples: the soft/hard-iron fit needs at '
                               'least 10, from many orientations')
    # Step 1: the ellipsoid of all samples (radius 1: T1 = T x |field|, µT).
    try:
        ml = fit_ml(mag, radius=1.0)
    except (CalibrationError, np.linalg.LinAlgError) as error:
        centre = 0.5 * (mag.max(axis=0) + mag.min(axis=0))
        coverage = sphere_coverage(mag - centre)
        raise CalibrationError(
            f'the magnetometer samples do not determine its soft and hard iron ({error}); '
            f'seen from the middle of their range they cover {coverage:.0%} of the sphere '
            'of directions (less about the true centre): turn the sensor through many '
            'orientations, upside down and on each side, while recording') from None
    T1, hard_iron = ml.T, ml.bias
    radius = float(np.linalg.det(T1)) ** (1.0 / 3.0)
    if not radius >= MIN_FIELD_TO_NOISE * ml.sigma:
        raise CalibrationError(
            f'the magnetometer samples hardly change direction (an ellipsoid of {radius:.2g} µT '
            f'fits them, {radius / ml.sigma:.1f} times their noise of {ml.sigma:.2g} µT; needs '
            f'{MIN_FIELD_TO_NOISE:g}): they cover 0% of the sphere of field directions; turn the '
            'sensor through many orientations, upside down and on each side, while recording')
    coverage = sphere_coverage(ml.directions)
    spread = float(np.linalg.eigvalsh(ml.directions.T @ ml.directions / n)[0])
    if coverage < min_coverage or (min_coverage > 0 and spread < MIN_SPREAD):
        raise CalibrationError(
            f'the magnetometer saw {coverage:.0%} of the sphere of field directions (needs '
            f'{min_coverage:.0%})'
            + (f' and they stay near one cone (spread {spread:.3f}, needs {MIN_SPREAD}: '
               'the sensor turned about one axis only)' if spread < MIN_SPREAD else '')
            + ': turn the sensor through more orientations, upside down and on each side, '
            'while recording')
    F = float(field_uT) if field_uT is not None else float(np.linalg.det(T1)) ** (1.0 / 3.0)
    corrected = np.linalg.solve(T1, (mag - hard_iron).T)
    residual_rms = float(np.sqrt(np.mean((np.linalg.norm(corrected, axis=0) - 1.0) ** 2))) * F
    # Step 2: R and the dip from the static windows.
    up, mag_means = _window_means(samples, windows, correct_accel, mag_ok)
    W = len(up)
    if W == 0:
        raise CalibrationError('no static window with magnetometer samples: hold a few poses '
                               'still while recording, for the alignment to the accelerometer')
    v = _field_directions(T1, hard_iron, mag_means)
    result = MagnetometerCalibration(
        T=T1 / F, hard_iron_uT=hard_iron, R=np.eye(3), field_uT=F, dip_deg=float('nan'),
        predicted_accuracy=float('inf'), coverage=coverage, residual_rms_uT=residual_rms,
        sigma_uT=float(ml.sigma), samples_used=n, windows_used=W)
    R, dip, r, J, converged = np.eye(3), None, None, None, False
    reason = None
    if W < min_windows:
        reason = f'only {W} static windows with magnetometer samples (needs {min_windows})'
    else:
        R, dip, r, J, converged = fit_alignment(up, v)
        sigma2 = float(np.sum(r * r)) / (W - 4)
        JtJ = J.T @ J
        try:
            step_cov = sigma2 * np.linalg.inv(JtJ)
        except np.linalg.LinAlgError:
            step_cov = np.full((4, 4), np.inf)
        std = np.degrees(np.sqrt(np.abs(np.diag(step_cov))))
        if not np.all(np.isfinite(std[:3])) or std[:3].max() > MAX_ALIGNMENT_STD_DEG:
            reason = (f'the static windows leave R undetermined (±{std[:3].max():.1f}°): hold '
                      'poses in more different orientations')
            R = np.eye(3)
    if reason is not None:
        s = np.clip(-np.einsum('ki,ij,kj->k', up, R.T, v), -1.0, 1.0)
        result.dip_deg = float(np.degrees(np.mean(np.arcsin(s))))
        result.dip_residual_deg = float(np.degrees(np.std(np.arcsin(s))))
        result.message = (f'magnetometer soft/hard iron from {n} samples ({coverage:.0%} of the '
                          f'sphere), field {F:.1f} µT; R kept at identity: {reason}')
        return result
    # Covariance: step 1 (ML), step 2, and step 1's errors carried into R and the dip.
    p_ml = np.concatenate([T1[UPPER], hard_iron])
    C_ml = np.asarray(ml.covariance, float)
    G = np.zeros((len(up), 9))
    for i in range(9):
        h = 1e-6 * max(abs(p_ml[i]), np.max(np.abs(T1)))
        d = np.zeros(9)
        d[i] = h
        rp = _dip_residuals(R, dip, up, _field_directions(*_unpack(p_ml + d), mag_means))[0]
        rm = _dip_residuals(R, dip, up, _field_directions(*_unpack(p_ml - d), mag_means))[0]
        G[:, i] = (rp - rm) / (2 * h)
    S = np.linalg.solve(J.T @ J, J.T @ G)           # d(theta, dip) / d p_ml = -S
    cov_step2 = step_cov + S @ C_ml @ S.T
    cov = np.zeros((13, 13))
    cov[:9, :9] = C_ml
    cov[9:, 9:] = cov_step2
    cov[9:, :9] = -S @ C_ml
    cov[:9, 9:] = cov[9:, :9].T
    result.covariance = cov[:12, :12]
    result.R = R
    result.dip_deg = float(np.degrees(dip))
    result.dip_std_deg = float(np.degrees(np.sqrt(cov[12, 12])))
    result.dip_residual_deg = float(np.degrees(np.sqrt(np.mean(r * r))))
    result.alignment_fitted = True
    M = _field_error_matrix(T1, hard_iron, R, field_uT is not None, F)
    value = float(np.sum(M * result.covariance))
    result.predicted_accuracy = float(np.sqrt(max(value, 0.0))) if np.isfinite(value) \
        else float('inf')
    result.converged = bool(ml.converged and converged
                            and np.isfinite(result.predicted_accuracy))
    result.message = (
        f'magnetometer from {n} samples ({coverage:.0%} of the sphere) and {W} static '
        f'windows: field {F:.1f} µT, dip {result.dip_deg:.1f}°, predicted accuracy '
        f'{result.predicted_accuracy:.3f} µT, residual {residual_rms:.3f} µT RMS'
        + ('' if result.converged else '; the iteration did not converge'))
    return result
