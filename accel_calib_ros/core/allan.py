"""
Allan deviation of a still recording: white noise, bias instability, rate random walk.

The overlapping Allan variance at cluster time tau = m dt is

    sigma²(tau) = sum_k (x_{k+2m} - 2 x_{k+m} + x_k)² / (2 tau² (N - 2m)),

with x the running integral of the signal (IEEE Std 952, the estimator allantools'
``oadev`` implements). Each point carries a chi² confidence interval from its
equivalent degrees of freedom (white-noise approximation, Howe's edf for the
overlapping estimator). From the curve, per axis:

- ``noise_density`` N: the -1/2 slope, sigma(tau) = N / sqrt(tau) (units/√Hz), read
  from the shortest cluster times (a least-squares fit of sigma² = N²/tau there).
  This is the package's one noise-density convention (:data:`NOISE_DENSITY_CONVENTION`;
  IEEE Std 952, Kalibr): for white noise the mean of tau seconds of samples has
  variance N²/tau, so N² is the level of the *two-sided* power spectral density
  (equivalently half the one-sided level: N = sqrt(S₁/2)) and white samples at rate f
  have std N sqrt(f) (``white_sample_std``, what a simulator draws). A *one-sided*
  density D, as quoted with an RMS of D sqrt(bandwidth) (the datasheet style, and what
  ``simulate.mpu9250_like`` draws: std = D sqrt(f/2)), is D = N sqrt(2). ``diagnose``
  and ``simulate --noise-from`` use the same N;
- ``bias_instability`` B: the flat bottom, B = min sigma / sqrt(2 ln 2 / pi) (only a
  bound, ``bias_instability_reached`` False, when the curve still falls at the end);
- ``random_walk`` K: the +1/2 slope, sigma(tau) = K sqrt(tau / 3), read from the
  longest cluster times (0 when the curve never rises).

Each has a confidence interval from the chi² interval of the points it was read at.
ROS-free, numpy and scipy only.
"""

from dataclasses import dataclass

import numpy as np

from .constants import G0
from .errors import CalibrationError, InputError

MIN_CLUSTERS = 9
"""A cluster time is kept only when this many independent clusters fit in the record."""

NOISE_DENSITY_CONVENTION = ('Allan N: sigma_allan(tau) = N/sqrt(tau) for white noise; '
                            'N**2 = two-sided PSD = one-sided PSD / 2; white samples at rate '
                            'f have std N*sqrt(f); a one-sided (datasheet-style) density is '
                            'N*sqrt(2)')
"""The one noise-density convention of the package (allan, diagnose, simulate, docs)."""

BI_FACTOR = float(np.sqrt(2.0 * np.log(2.0) / np.pi))
"""sigma at the flat bottom of the curve over the bias instability (0.664)."""


@dataclass
class AllanResult:
    """Allan deviation per axis and the noise terms read from it."""

    axes: list
    tau: np.ndarray                  # (M,) s
    adev: np.ndarray                 # (A, M)
    adev_ci: np.ndarray              # (A, M, 2)
    noise_density: np.ndarray        # (A,)
    noise_density_ci: np.ndarray     # (A, 2)
    bias_instability: np.ndarray     # (A,)
    bias_instability_ci: np.ndarray  # (A, 2)
    bias_instability_tau: np.ndarray  # (A,) s
    random_walk: np.ndarray          # (A,)
    random_walk_ci: np.ndarray       # (A, 2)
    rate_hz: float
    duration_s: float

    @property
    def bias_instability_reached(self):
        """Return per axis whether the curve has a bottom (False: still falling, a bound)."""
        return self.bias_instability_tau < self.tau[-1]

    def summary(self):
        """Return the JSON object of interface.md §8 (lists, finite numbers)."""
        return {
            'axes': list(self.axes), 'rate_hz': self.rate_hz, 'duration_s': self.duration_s,
            'tau': self.tau.tolist(), 'adev': self.adev.tolist(),
            'adev_ci': self.adev_ci.tolist(),
            'noise_density': self.noise_density.tolist(),
            'noise_density_ci': self.noise_density_ci.tolist(),
            'bias_instability': self.bias_instability.tolist(),
            'bias_instability_ci': self.bias_instability_ci.tolist(),
            'bias_instability_tau': self.bias_instability_tau.tolist(),
            'bias_instability_reached': self.bias_instability_reached.tolist(),
            'random_walk': self.random_walk.tolist(),
            'random_walk_ci': self.random_walk_ci.tolist(),
            'white_sample_std': self.white_sample_std().tolist(),
            'noise_density_ug_rthz': [float(v / G0 * 1e6) if a.startswith('a') else None
                                      for a, v in zip(self.axes, self.noise_density)],
            'noise_density_convention': NOISE_DENSITY_CONVENTION,
            'units': {'accel': {'noise_density': 'm/s²/√Hz', 'bias_instability': 'm/s²',
                                'random_walk': 'm/s² per √s'},
                      'gyro': {'noise_density': 'rad/s/√Hz', 'bias_instability': 'rad/s',
                               'random_walk': 'rad/s per √s'}},
            'confidence': 0.95,
        }

    def white_sample_std(self):
        """Return the per-sample std of the white part at the recording's rate (simulator)."""
        return self.noise_density * np.sqrt(self.rate_hz)

    def text(self):
        """Return the human summary, one line per axis."""
        lines = [f'{self.duration_s:.0f} s at {self.rate_hz:.0f} Hz; tau {self.tau[0]:.3g} to '
                 f'{self.tau[-1]:.3g} s (95 % intervals); noise density N as Allan: '
                 'σ(τ) = N/√τ, white samples std N·√rate (one-sided density = N·√2)']
        for i, axis in enumerate(self.axes):
            ug = (f' ({self.noise_density[i] / G0 * 1e6:.0f} µg/√Hz)'
                  if axis.startswith('a') else '')
            lines.append(
                f'{axis}: noise density {self.noise_density[i]:.3g} '
                f'[{self.noise_density_ci[i, 0]:.3g}, {self.noise_density_ci[i, 1]:.3g}] '
                f'/√Hz{ug}, '
                f'bias instability {"" if self.bias_instability_reached[i] else "<= "}'
                f'{self.bias_instability[i]:.3g} '
                f'[{self.bias_instability_ci[i, 0]:.3g}, {self.bias_instability_ci[i, 1]:.3g}] '
                f'at {self.bias_instability_tau[i]:.3g} s, random walk '
                f'{self.random_walk[i]:.3g} [{self.random_walk_ci[i, 0]:.3g}, '
                f'{self.random_walk_ci[i, 1]:.3g}] /√s')
        return '\n'.join(lines)


def cluster_sizes(n, per_decade=8):
    """Return cluster sizes m, log-spaced, with at least ``MIN_CLUSTERS`` clusters in n."""
    top = n // MIN_CLUSTERS
    if top < 1:
        return np.zeros(0, int)
    grid = np.logspace(0, np.log10(top), max(int(np.log10(top) * per_decade) + 1, 1))
    return np.unique(np.round(grid).astype(int))


def overlapping_adev(x, rate_hz, sizes):
    """
    Return the overlapping Allan deviation of ``x`` (n, A) at cluster sizes ``sizes``, (A, M).

    :param x: samples, one column per axis.
    :param rate_hz: sample rate, Hz.
    :param sizes: (M,) cluster sizes in samples.
    """
    x = np.asarray(x, float)
    phase = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x - x.mean(axis=0), axis=0)])
    phase /= rate_hz
    out = np.empty((x.shape[1], len(sizes)))
    for j, m in enumerate(sizes):
        tau = m / rate_hz
        d = phase[2 * m:] - 2.0 * phase[m:-m] + phase[:-2 * m]
        out[:, j] = np.sqrt(np.sum(d ** 2, axis=0) / (2.0 * tau ** 2 * len(d)))
    return out


def _edf(n, m):
    """Return the equivalent degrees of freedom of an overlapping ADEV point (white noise)."""
    return max((3.0 * (n - 1) / (2.0 * m) - 2.0 * (n - 2) / n) * 4.0 * m ** 2
               / (4.0 * m ** 2 + 5.0), 1.0)


def _ci(value, edf, level=0.95):
    """Return the chi² confidence interval of a deviation estimated with ``edf`` dof."""
    from scipy import stats
    lo = np.sqrt(edf / stats.chi2.ppf(0.5 + level / 2.0, edf))
    hi = np.sqrt(edf / stats.chi2.ppf(0.5 - level / 2.0, edf))
    return np.array([value * lo, value * hi])


def allan(samples, include_gyro=True, min_duration_s=10.0):
    """
    Characterise the noise of a still recording, per axis.

    :param samples: Samples (validated), held still the whole time.
    :param include_gyro: also the gyro axes when recorded.
    :param min_duration_s: shortest recording worth a curve, s.
    :returns: AllanResult.
    :raises InputError: most time stamps repeat (median step 0).
    :raises CalibrationError: the recording is too short, or not sampled evenly enough,
        or an accelerometer axis never changes (a constant gyro axis leaves the gyro out).
    """
    n = len(samples)
    rate = samples.rate_hz
    duration = float(samples.t[-1] - samples.t[0]) if n > 1 else 0.0
    if n >= 2 and not np.isfinite(rate):      # the median step is 0: most stamps repeat
        raise InputError(f'most of the {n} rows share their time stamp with the row before: '
                         'write t with more digits (seconds with at least 1 ms resolution)')
    if not np.isfinite(rate) or rate <= 0 or duration < min_duration_s or n < 100:
        raise CalibrationError(
            f'the recording lasts {duration:.1f} s ({n} samples); an Allan curve needs at '
            f'least {min_duration_s:.0f} s and 100 samples of a still sensor (minutes to '
            'hours for bias instability)')
    stuck = [name for name, col in zip(('ax', 'ay', 'az'), samples.accel.T)
             if np.ptp(col) == 0.0]
    if stuck:
        raise CalibrationError(
            f'{", ".join(stuck)} never change over {n} samples: a stuck or disconnected '
            'sensor (or data written with too few digits) has no noise to characterise')
    columns, axes = [samples.accel], ['ax', 'ay', 'az']
    if include_gyro and samples.gyro is not None and np.all(np.ptp(samples.gyro, axis=0) > 0):
        columns.append(samples.gyro)
        axes += ['gx', 'gy', 'gz']
    x = np.hstack(columns)
    sizes = cluster_sizes(n)
    tau = sizes / rate
    adev = overlapping_adev(x, rate, sizes)
    edf = np.array([_edf(n, m) for m in sizes])
    adev_ci = np.stack([np.stack([_ci(adev[a, j], edf[j]) for j in range(len(sizes))])
                        for a in range(len(axes))])
    k = len(axes)
    density, density_ci = np.zeros(k), np.zeros((k, 2))
    bias, bias_ci, bias_tau = np.zeros(k), np.zeros((k, 2)), np.zeros(k)
    walk, walk_ci = np.zeros(k), np.zeros((k, 2))
    short = tau <= max(tau[min(2, len(tau) - 1)], 10.0 / rate)
    for a in range(k):
        # White noise: sigma² tau = N² at the shortest cluster times (weighted by edf).
        w = edf[short]
        n2 = np.sum(w * adev[a, short] ** 2 * tau[short]) / np.sum(w)
        density[a] = np.sqrt(n2)
        density_ci[a] = _ci(density[a], np.sum(w))
        j = int(np.argmin(adev[a]))
        bias[a] = adev[a, j] / BI_FACTOR
        bias_ci[a] = _ci(bias[a], edf[j])
        bias_tau[a] = tau[j]
        # Rate random walk: the +1/2 slope after the bottom, sigma = K sqrt(tau / 3).
        after = np.arange(len(tau)) > j
        if after.sum() >= 2:
            slope = np.polyfit(np.log(tau[after]), np.log(adev[a, after]), 1)[0]
            if slope > 0.25:
                last = len(tau) - 1
                walk[a] = adev[a, last] / np.sqrt(tau[last] / 3.0)
                walk_ci[a] = _ci(walk[a], edf[last])
        if walk[a] == 0.0:
            # Not resolved: the upper bound the longest cluster time allows.
            last = len(tau) - 1
            walk_ci[a] = [0.0, _ci(adev[a, last], edf[last])[1] / np.sqrt(tau[last] / 3.0)]
    return AllanResult(axes, tau, adev, adev_ci, density, density_ci, bias, bias_ci,
                       bias_tau, walk, walk_ci, float(rate), duration)
