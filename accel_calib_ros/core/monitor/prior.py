"""
What a sensor may do between sessions and with temperature: its history, else the datasheet.

Two sizes the health check allows for on a calibration that is fine (:mod:`.health`):

- the **allowance**: the bias change per axis from one power-up (session) to the next.
  With a history of at least ``MIN_CALIBRATIONS`` calibrations of this sensor
  (``dataio.history`` keeps them), it is their session-to-session bias scatter per axis
  (the sample standard deviation, raised to its one-sided 84 % confidence bound for so
  few sessions, within ``ALLOWANCE_FLOOR`` .. ``ALLOWANCE_CAP``); else the setting
  (1 mg: the MPU-6050 recordings' power-up changes; the MPU-9250 datasheet gives no
  power-up repeatability);
- the **temperature coefficient** of the bias, for a temperature outside the calibrated
  range: the thermal tables' own slope at the range's edge (plus ``TABLE_DOUBT``: every
  model extrapolates poorly), else the slope of the history's biases against their
  sessions' temperatures (when they span ``MIN_SPAN_C``), else the datasheet's
  ``DATASHEET_TEMPCO`` (MPU-9250: zero-g level change ±1.5 mg/°C).
"""

from dataclasses import dataclass
import math

import numpy as np

from .stats import chi2_quantile
from ..constants import G0

MG = G0 * 1e-3
DATASHEET_TEMPCO = 1.5 * MG
"""MPU-9250 zero-g level change vs temperature, m/s² per °C."""
TABLE_DOUBT = 0.5 * MG
"""Added to the thermal tables' slope outside their range, m/s² per °C."""
MIN_CALIBRATIONS = 3
"""Calibrations in the history before its scatter is believed."""
MIN_SPAN_C = 5.0
"""Temperature span of the history's sessions before its slope is believed, °C."""
ALLOWANCE_FLOOR = 0.3 * MG
"""Smallest allowance taken from a history, m/s² (re-fits scatter that much at least)."""
ALLOWANCE_CAP = 10.0 * MG
"""Largest allowance taken from a history, m/s² (beyond: sensors mixed up, or damage)."""


@dataclass
class SensorPrior:
    """
    The allowance and the temperature coefficient, per axis, with where they come from.

    :param allowance: (3,) m/s². :param allowance_source: words.
    :param tempco: (3,) m/s² per °C. :param tempco_source: words.
    """

    allowance: np.ndarray
    allowance_source: str
    tempco: np.ndarray
    tempco_source: str

    def to_dict(self):
        """Return a JSON-ready dict, mg and mg/°C."""
        return {'allowance_mg': [float(v / MG) for v in self.allowance],
                'allowance_source': self.allowance_source,
                'tempco_mg_per_c': [float(v / MG) for v in self.tempco],
                'tempco_source': self.tempco_source}


def sensor_prior(allowance, calibrations=None, sensor=''):
    """
    Return the :class:`SensorPrior` of a sensor.

    :param allowance: the setting, m/s² per axis (used without a history).
    :param calibrations: the history's calibrations of this sensor (dicts with ``bias``
        (3,) m/s² and ``temperature_range_c`` (low, high) or None), or None.
    :param sensor: its id, for the words.
    """
    prior = SensorPrior(np.full(3, float(allowance)), 'the setting (health_allowance_mg)',
                        np.full(3, DATASHEET_TEMPCO), 'the MPU-9250 datasheet (1.5 mg/degC)')
    rows = [c for c in calibrations or [] if c.get('bias') is not None]
    biases = np.array([np.asarray(c['bias'], float).reshape(3) for c in rows]).reshape(-1, 3)
    keep = np.all(np.isfinite(biases), axis=1)
    biases, rows = biases[keep], [r for r, k in zip(rows, keep) if k]
    if len(biases) >= MIN_CALIBRATIONS:
        dof = len(biases) - 1
        upper = math.sqrt(dof / chi2_quantile(0.84, dof))
        spread = biases.std(axis=0, ddof=1) * upper
        prior.allowance = np.clip(spread, ALLOWANCE_FLOOR, ALLOWANCE_CAP)
        name = sensor or 'this sensor'
        prior.allowance_source = (f'the bias scatter of {len(biases)} calibrations in the '
                                  f'history of {name}')
    temps = np.array([0.5 * (r['temperature_range_c'][0] + r['temperature_range_c'][1])
                      if r.get('temperature_range_c') else np.nan for r in rows])
    ok = np.isfinite(temps)
    if ok.sum() >= MIN_CALIBRATIONS and np.ptp(temps[ok]) >= MIN_SPAN_C:
        x = temps[ok] - temps[ok].mean()
        y = biases[ok]
        slope = (x @ (y - y.mean(axis=0))) / (x @ x)
        resid = y - y.mean(axis=0) - np.outer(x, slope)
        se = np.sqrt(np.sum(resid ** 2, axis=0) / max(len(x) - 2, 1) / (x @ x))
        prior.tempco = np.clip(np.abs(slope) + 2.0 * se, 0.1 * MG, 2.0 * DATASHEET_TEMPCO)
        prior.tempco_source = (f'the bias against temperature of {int(ok.sum())} calibrations '
                               'in the history')
    return prior


def table_tempco(cal, raw, temp):
    """
    Return the thermal tables' slope at the edge of their range nearest ``temp``, (3,).

    :param cal: Calibration with ``thermal`` and ``drift(raw, temp)``.
    :param raw: (3,) a raw reading at the orientation in question, m/s².
    :param temp: the temperature, °C (outside the tables' range).
    :return: |d drift / dT| + ``TABLE_DOUBT`` per axis, m/s² per °C, or None.
    """
    thermal = getattr(cal, 'thermal', None)
    rng = None if thermal is None else thermal.range_c
    if rng is None:
        return None
    low, high = rng
    edge, inside = (high, high - 2.0) if temp > high else (low, low + 2.0)
    raw = np.asarray(raw, float).reshape(1, 3)
    try:
        with np.errstate(all='ignore'):
            a = np.asarray(cal.drift(raw, np.array([edge])), float).reshape(3)
            b = np.asarray(cal.drift(raw, np.array([inside])), float).reshape(3)
    except (ValueError, TypeError, AttributeError):
        return None
    slope = np.abs(a - b) / abs(edge - inside)
    if not np.all(np.isfinite(slope)):
        return None
    return slope + TABLE_DOUBT
