"""
The thermal calibration of one still pose, for every front door (``fit``, the node).

:func:`fit_thermal` takes a still recording whose temperature sweeps (a warm-up, a chamber
cycle) and an existing calibration (its T and bias, fitted at its own temperature) and
returns that calibration plus offset tables against temperature, the gyroscope bias against
temperature from the same data, and, when the data support it, the heating/cooling
hysteresis term the model-gap workflow names (``modelgap.still_pose``): the same selection,
criterion and naming power as ``diagnose``, so that ``fit`` carries exactly the effect
``diagnose`` names. The tables are zero at the calibration's own temperature, so its
correction there is unchanged. Nothing is written here (:mod:`.persist` saves).
"""

import copy
from dataclasses import dataclass, field

import numpy as np

from ..core.accelerometer.thermal_pose import fit_still
from ..core.accelerometer.thermal_still import BIN_S, MIN_THERMAL_SPAN_C, still_bins

STILL_BAND_WIDTH_C = 5.0
"""Default band width of a one-pose thermal fit, °C (dense data: finer nodes than poses)."""


@dataclass
class ThermalSettings:
    """
    What a front door asks of a one-pose thermal fit.

    :param band_width_c: band width of the offset tables, °C.
    :param bin_s: bin length, s. :param min_span_c: smallest temperature span, °C.
    :param hysteresis: 'auto' (when the model-gap selection names it), 'off'.
    :param gravity: local gravity, m/s² (the worst case in mg).
    :param min_effect_mg: practical threshold for naming a hysteresis term, mg (None: the
        workflow's default).
    :param source: where the data came from (written into the calibration).
    """

    band_width_c: float = STILL_BAND_WIDTH_C
    bin_s: float = BIN_S
    min_span_c: float = MIN_THERMAL_SPAN_C
    hysteresis: str = 'auto'
    gravity: float = 9.80665
    min_effect_mg: float = None
    source: str = ''


@dataclass
class ThermalOutcome:
    """
    The result of :func:`fit_thermal`.

    :param calibration: the reference calibration plus the thermal part, or None (refused).
    :param fit: core.accelerometer.thermal_pose.StillFit, or None.
    :param recording: the StillRecording (bins, poses, what was left out), or None.
    :param reference_c: the temperature the tables are zero at, °C.
    :param reference_note: how it was chosen.
    :param diagnosis: the model-gap result on the recording (modelgap DiagnoseResult), or
        None when it was not run.
    :param warnings: lines for the user.
    :param refusal: the reason nothing may be saved, or None.
    """

    calibration: object = None
    fit: object = None
    recording: object = None
    reference_c: float = None
    reference_note: str = ''
    diagnosis: object = None
    warnings: list = field(default_factory=list)
    refusal: str = None


def reference_temperature(cal, rec):
    """
    Return the temperature the reference calibration holds at, °C, and how it was found.

    Its thermal tables' own reference, else the middle of the temperature range its fit
    saw, else (a calibration that records no temperature) the recording's median, said so.
    """
    if cal.thermal is not None and cal.thermal.reference_c is not None:
        return float(cal.thermal.reference_c), "the calibration's thermal reference"
    if cal.temperature_range_c is not None:
        low, high = cal.temperature_range_c
        return 0.5 * (low + high), "the middle of the calibration's temperature range"
    median = float(np.median(rec.bins.temp))
    return median, ('the calibration records no temperature: its bias is taken to hold at '
                    f"{median:.1f} °C, the recording's median")


def fit_thermal(samples, reference, settings=None):
    """
    Fit the thermal part of a calibration to a still recording (see the module docstring).

    :param samples: Samples in m/s² (converted as the reference calibration's input).
    :param reference: core.calibration.Calibration to extend (not changed).
    :param settings: ThermalSettings.
    :returns: ThermalOutcome (``refusal`` set, ``calibration`` None, when the recording
        cannot carry a thermal fit).
    """
    from ..core.errors import CalibrationError
    settings = settings or ThermalSettings()
    try:
        rec = still_bins(samples, settings.bin_s, settings.min_span_c)
    except CalibrationError as err:
        return ThermalOutcome(refusal=str(err))
    return fit_thermal_recording(rec, reference, settings)


def fit_thermal_recording(rec, reference, settings=None):
    """
    Fit the thermal part of a calibration to a checked still recording (bins).

    :param rec: StillRecording (``core.accelerometer.thermal_still``: from a recording, or
        the calibration node's live bins); its ``samples`` give the bins' noise from their
        own spectrum when they are there.
    :param reference: core.calibration.Calibration to extend (not changed).
    :param settings: ThermalSettings.
    :returns: ThermalOutcome.
    """
    from ..core.errors import CalibrationError
    settings = settings or ThermalSettings()
    out = ThermalOutcome(recording=rec)
    out.reference_c, out.reference_note = reference_temperature(reference, rec)
    hysteresis = None
    if settings.hysteresis != 'off':
        from ..modelgap.still_pose_run import diagnose_still
        try:
            out.diagnosis = diagnose_still(rec, reference, out.reference_c,
                                           settings.band_width_c, settings.gravity,
                                           min_effect_mg=settings.min_effect_mg,
                                           samples=rec.samples, power=False)
        except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
            out.warnings.append(f'hysteresis not checked: {err}')
        else:
            hysteresis = out.diagnosis.hysteresis()
    fit = fit_still(rec, out.reference_c, settings.band_width_c, hysteresis,
                    reference.gyro_bias)
    out.fit = fit
    out.calibration = extended(reference, fit, settings.source)
    heating, cooling = fit.legs.get('heating_bins', 0), fit.legs.get('cooling_bins', 0)
    if min(heating, cooling) < 10 <= max(heating, cooling):
        seen, unseen = ('heats', 'cooling') if heating > cooling else ('cools', 'heating')
        if fit.table.hysteresis is not None:
            out.warnings.append(
                f'the recording only {seen}: the hysteresis term, fitted from how the rate '
                f'varied, predicts {unseen}, which was not seen; record a {unseen} leg to '
                'check it (a chamber cycle, or a cool-down after the warm-up)')
        else:
            out.warnings.append(
                f'the recording only {seen}: how the sensor reads while {unseen} is unknown '
                '(real parts differ by several mg between heating and cooling); the '
                f'predicted accuracy covers {"heating" if heating > cooling else "cooling"} '
                f'only: record a {unseen} leg too (a chamber cycle, or a cool-down after the '
                'warm-up)')
    low, high = rec.temp_range_c
    if not low <= out.reference_c <= high:
        out.warnings.append(
            f"the calibration's own temperature ({out.reference_c:.1f} °C) lies outside the "
            f'recording ({low:.1f} .. {high:.1f} °C): the tables are extrapolated to it')
    return out


def extended(reference, fit, source=''):
    """Return a copy of ``reference`` with the thermal part of ``fit`` (a StillFit)."""
    cal = copy.copy(reference)
    cal.thermal = fit.table
    low, high = fit.table.range_c
    if reference.temperature_range_c is not None:
        low = min(low, reference.temperature_range_c[0])
        high = max(high, reference.temperature_range_c[1])
    cal.temperature_range_c = (low, high)
    cal.created = ''
    cal.__post_init__()
    if source:
        cal.source = (f'{reference.source} + thermal: {source}' if reference.source
                      else f'thermal: {source}')
    return cal
