"""The ``thermal`` block of a calibration file: band tables, their range and hysteresis."""

from .yaml_schema import _found, _mapping, _number, _optional, _string, _vector, Bad
from ..core.accelerometer.thermal import ThermalBand, ThermalTable
from ..core.accelerometer.thermal_lag import Hysteresis, LAG_GAP_S
from ..core.calibration import MAX_GYRO_BIAS


def thermal_table(value, gravity_raw, max_bands, temperature_range):
    """Parse the ``thermal`` block into a ThermalTable (``Bad`` with the reason)."""
    d = _mapping(value, 'thermal')
    width = _number(d.get('band_width_c'), 'thermal.band_width_c', 1e-3, 1e3)
    bands_in = d.get('bands', [])
    if not isinstance(bands_in, list) or len(bands_in) > max_bands:
        raise Bad(f'thermal.bands must be a list of at most {max_bands} bands')
    lo_t, hi_t = temperature_range
    bands = []
    for k, b in enumerate(bands_in):
        name = f'thermal.bands[{k}]'
        b = _mapping(b, name)
        low = _number(b.get('low_c'), f'{name}.low_c', lo_t, hi_t)
        high = _number(b.get('high_c'), f'{name}.high_c', lo_t, hi_t)
        if not low < high:
            raise Bad(f'{name}: low_c must be below high_c')
        temp = _number(b.get('temp_c'), f'{name}.temp_c', lo_t, hi_t)
        quad = _vector(b.get('quadratic_per_m_s2'), f'{name}.quadratic_per_m_s2', 3,
                       -1.0 / gravity_raw, 1.0 / gravity_raw)
        lin = _vector(b.get('linear'), f'{name}.linear', 3, -1.0, 1.0)
        off = _vector(b.get('offset_m_s2'), f'{name}.offset_m_s2', 3, -gravity_raw,
                      gravity_raw)
        windows = _number(b.get('windows', 0), f'{name}.windows', 0, 1e12, integer=True)
        status = _string(b.get('status', 'ok'), f'{name}.status')
        rms = _optional(b, 'residual_rms_m_s2',
                        lambda v: _number(v, f'{name}.residual_rms_m_s2', 0.0))
        gyro = _optional(b, 'gyro_bias_rad_s',
                         lambda v: _vector(v, f'{name}.gyro_bias_rad_s', 3, -MAX_GYRO_BIAS,
                                           MAX_GYRO_BIAS))
        if status == 'ok' and not low <= temp <= high:
            raise Bad(f'{name}: temp_c {temp:g} lies outside its band [{low:g}, {high:g}]')
        bands.append(ThermalBand(low, high, temp, quad, lin, off, windows, status,
                                 float('nan') if rms is None else rms, gyro))
    for a, b in zip(bands, bands[1:]):
        if not a.high_c <= b.low_c + 1e-9:
            raise Bad('thermal bands must be ordered by temperature and must not overlap')
    extrapolation = _string(d.get('extrapolation', 'hold'), 'thermal.extrapolation', 20)
    if extrapolation not in ('hold', 'linear'):
        raise Bad(f'thermal.extrapolation must be hold or linear, found {_found(extrapolation)}')
    source = _string(d.get('source', 'poses'), 'thermal.source', 20)
    if source not in ('poses', 'still'):
        raise Bad(f'thermal.source must be poses or still, found {_found(source)}')
    reference = _optional(d, 'reference_c',
                          lambda v: _number(v, 'thermal.reference_c', lo_t, hi_t))
    span = _optional(d, 'calibrated_c',
                     lambda v: _vector(v, 'thermal.calibrated_c', 2, lo_t, hi_t))
    if span is not None and span[0] > span[1]:
        raise Bad('thermal.calibrated_c must be [low, high]')
    hysteresis = _optional(d, 'hysteresis', lambda v: _hysteresis(v, gravity_raw))
    return ThermalTable(width, bands, extrapolation, reference,
                        None if span is None else tuple(span), hysteresis, source)


def _hysteresis(value, gravity_raw):
    """Parse ``thermal.hysteresis``: the heating/cooling term (tau, offset per °C of lag)."""
    h = _mapping(value, 'thermal.hysteresis')
    effect = _string(h.get('effect', 'temperature_rate'), 'thermal.hysteresis.effect', 60)
    tau = _number(h.get('tau_s'), 'thermal.hysteresis.tau_s', 0.1, 1e6)
    k = _vector(h.get('offset_per_c_m_s2'), 'thermal.hysteresis.offset_per_c_m_s2', 3,
                -0.1 * gravity_raw, 0.1 * gravity_raw)
    gap = _number(h.get('gap_s', LAG_GAP_S), 'thermal.hysteresis.gap_s', 1.0, 1e6)
    return Hysteresis(tau, k, effect, gap)
