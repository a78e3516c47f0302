"""
The model-gap check after a calibration: what the data show that the model does not include.

The calibration node runs it after each ``~/calibrate`` (off the response's path) and
publishes the result on ``~/status``; ``modelgap.diagnose_windows`` does the work on the
session's windows. Effects the calibration already models (those the temperature tables
model, ``Effect.modelled_by_thermal_tables``, when it has usable bands) are not reported
as missing.
"""

import numpy as np

from ..core.errors import CalibrationError, InputError
from ..core.finite import finite_or_none


def model_gap(windows, baseline, gravity, rate_hz=None, thermal_bands=None, method=None):
    """
    Run the model-gap check on a session's windows; return a JSON-ready dict, or None.

    :param windows: the session's :class:`~.windows.WindowSet`.
    :param baseline: 'ml' or 'gn' (the model the calibration used).
    :param gravity: local gravity, m/s².
    :param rate_hz: the sample rate, Hz (for the noise density), or None.
    :param thermal_bands: usable temperature bands of the calibration (their effects
        are modelled), or None.
    :param method: the method's name in the note (default ``baseline``).
    :return: dict ``baseline``, ``missing_effects``, ``gap_before``, ``gap_after``,
        ``note``; ``{'missing_effects': [], 'note': 'skipped: ...'}`` when it cannot run;
        None without windows.
    """
    from ..modelgap import diagnose_windows
    from ..modelgap.effects import EFFECTS
    if windows is None or not len(windows):
        return None
    try:
        report = diagnose_windows(windows.to_static_windows(), baseline, gravity,
                                  rate_hz=rate_hz, replicates=0)
    except (CalibrationError, InputError, ValueError, np.linalg.LinAlgError) as err:
        return {'missing_effects': [], 'note': f'skipped: {err}'}
    steps = [s for s in report.steps
             if not (thermal_bands and EFFECTS[s['effect']].modelled_by_thermal_tables)]
    gap = {'baseline': baseline, 'missing_effects': [s['effect'] for s in steps],
           'gap_before': finite_or_none(report.gap_before, 3),
           'gap_after': finite_or_none(report.gap_after, 3), 'note': ''}
    if steps:
        details = '; '.join(f'{s["effect"]} ({s["evidence"]["magnitude"]})' for s in steps)
        gap['note'] = (f'the data show {details}, which the {method or baseline} model does '
                       'not include')
    return gap
