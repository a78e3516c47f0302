"""
What a front door asks of a session (:class:`Settings`) and how it spells it (:class:`Words`).

Every default a door offers (the acceptance limits, the weight cap of a window, the
methods) is a field default of :class:`Settings`: the node's parameters, the options of
``accel-calib fit`` and of ``guide`` read them from :data:`DEFAULT_SETTINGS`, so the three doors
cannot drift apart. The limits themselves are the science's (``core``); this is where a
door finds them.

Each door has one :class:`Words`: :data:`NODE` (parameters and topics), :data:`FIT`
(options of ``accel-calib fit``) and :data:`GUIDE` (options of ``accel-calib guide``,
which has fewer: its refusals never name one it does not have). Nothing below the
session floor spells a door's option or parameter.

Light to import: the ``--help`` of every command reads the defaults.
"""

from typing import NamedTuple, Optional

from ..core.calibration import MAX_BIAS_G, MAX_CROSS_AXIS, MAX_SCALE_ERROR
from ..core.constants import G0
from ..core.outcomes import DEFAULT_MAX_GYRO_ERROR, DEFAULT_MAX_MAG_ERROR
from ..core.windows import MAX_WEIGHT_S

THERMAL_MODES = ('auto', 'on', 'off')
"""When temperature-band tables are fitted: always, never, or when two bands are filled."""
LIVE_METHODS = ('ml', 'gn', 'ml-bc')
"""The methods a live session (the calibration node) offers: not the algebraic ellipsoid."""
GUIDED_METHODS = ('ml', 'gn')
"""The methods whose advice the guide can give (``core.advice``)."""
SI_UNITS = {'accel': 'm/s2'}
"""The ``input_units`` of readings that come in m/s² (sensor_msgs/Imu, the guide's sources)."""


class Words(NamedTuple):
    """
    How a front door spells what its user can change (an option, a parameter) and sees.

    A name left empty is not mentioned (the door has no such option).

    :param limit: the name of the predicted-accuracy limit.
    :param residual_limit: the name of the residual-ratio limit.
    :param gyro_limit: the name of the gyroscope's limit; ``mag_limit`` the magnetometer's.
    :param unit: the spelling of m/s².
    :param ml_hint: how to ask for the 9-parameter method.
    :param thermal_hint: how to switch the temperature tables on.
    :param follow_up: added to a residual refusal (where to learn what the model misses).
    :param unconverged: added to a refusal of a fit that did not converge.
    :param no_windows: the refusal when nothing was collected.
    :param no_temperature: the refusal of temperature tables without temperatures
        (None: the fit's own words).
    :param implausible: format of the refusal of a calibration no file may hold.
    :param no_gyro: why the gyroscope is absent (the input has no angular rate).
    :param no_mag: why the magnetometer is absent (the input has no field).
    :param no_samples: why both are absent (no sample came at all).
    :param mag_unusable: magnetometer samples came, none usable.
    :param gyro_not_kept: the door keeps no raw samples for the gyroscope fit.
    :param mag_not_kept: the door keeps no magnetometer samples.
    :param ring_short: added to an insufficient gyroscope when only the last ``{seconds}``
        of raw samples were kept.
    :param stopping: the refusal of a session the door stopped right before its save.
    """

    limit: str = '--max-predicted-error'
    residual_limit: str = '--max-residual-ratio'
    gyro_limit: str = '--max-gyro-error'
    mag_limit: str = '--max-mag-error'
    unit: str = 'm/s²'
    ml_hint: str = 'use --method ml'
    thermal_hint: str = 'add --thermal'
    follow_up: str = '; accel-calib diagnose DATA names what the model does not include'
    unconverged: str = '; nothing written (--force writes it anyway)'
    no_windows: str = 'no static windows found'
    no_temperature: Optional[str] = None
    implausible: str = 'the fitted calibration is implausible ({err}); are the data in m/s²?'
    no_gyro: str = 'the data have no gx gy gz'
    no_mag: str = 'the data have no mx my mz'
    no_samples: str = 'no samples'
    mag_unusable: str = 'no row holds a magnetometer sample'
    gyro_not_kept: str = 'no raw samples were kept'
    mag_not_kept: str = 'no magnetometer samples were kept'
    ring_short: str = ' (only the last {seconds:.0f} s of raw samples were kept)'
    stopping: str = 'stopped before the save: nothing was written'


FIT = Words()
"""The words of ``accel-calib fit`` (its options, the columns of its data)."""
GUIDE = Words(residual_limit='', gyro_limit='', mag_limit='',
              thermal_hint='record the session (--record FILE) and fit it with accel-calib '
                           'fit --thermal',
              follow_up='; record the session (--record FILE) and run accel-calib diagnose '
                        'on it to name what the model does not include',
              unconverged='; nothing written',
              no_windows='no pose was held still long enough to count',
              implausible='the fitted calibration is implausible ({err})',
              no_gyro='the source gives no angular rate',
              no_mag='the source has no magnetometer', no_samples='no samples received',
              mag_unusable='no usable magnetometer sample received')
"""The words of ``accel-calib guide`` (a live session in the terminal, fewer options)."""
NODE = Words(limit='max_predicted_error', residual_limit='max_residual_ratio',
             gyro_limit='max_gyro_error', mag_limit='max_mag_error', unit='m/s2',
             ml_hint="set the parameter 'method' to ml", thermal_hint='try thermal:=auto',
             follow_up='; the model-gap check follows on ~/status', unconverged='',
             no_windows='no static windows collected yet: hold the sensor still in at '
                        'least 10 different orientations, 2 s each',
             no_temperature='thermal:=on but no temperature was received',
             implausible='refusing to write the calibration: {err}',
             no_gyro='imu/data_raw carries no angular velocity',
             no_mag='no imu/mag received', no_samples='no imu/data_raw received',
             mag_unusable='no usable imu/mag sample',
             gyro_not_kept='the node keeps no raw samples (max_gyro_samples is 0)',
             mag_not_kept='the node keeps no magnetometer samples (max_mag_samples is 0)',
             ring_short=' (only the last {seconds:.0f} s of raw samples are kept: '
                        'max_gyro_samples)',
             stopping='the node is shutting down: nothing was saved (the collected windows '
                      'end with the node)')
"""The words of the calibration node (parameters, topics)."""


class Settings(NamedTuple):
    """
    What a front door asks of the fit, of its acceptance and of the file.

    :param method: one of ``core.calibration.METHODS`` (the door may offer fewer).
    :param gravity: local gravity, m/s².
    :param thermal: one of :data:`THERMAL_MODES`.
    :param band_width_c: width of a temperature band, °C.
    :param max_predicted_error: acceptance limit of the predicted accuracy (RMS error at
        1 g over all orientations), m/s².
    :param max_residual_ratio: refuse when the gravity-norm residual RMS exceeds this
        many times the error expected of a window mean (None: not checked).
    :param max_weight_s: a window weighs at most this many seconds of samples.
    :param refuse_unphysical: refuse a fit no accelerometer in m/s² has (else a warning).
    :param max_scale_error: physical limit of ``|T_ii - 1|``.
    :param max_cross_axis: physical limit of ``|T_ij| / T_ii``.
    :param max_bias_g: physical limit of a bias, g.
    :param allow_unconverged: accept a fit that did not converge (``--force``).
    :param max_gyro_error: the gyroscope's limit (relative); ``max_mag_error`` (µT).
    :param field_uT: known field magnitude, µT, or None (fitted).
    :param sensor_id: the sensor's name, written into the calibration (None: none).
    :param input_units: how the readings were turned into m/s² (``accel``: 'm/s2', 'g' or
        'counts' with ``counts_per_g`` and ``counts_offset``), written into the
        calibration: it is right only for readings converted the same way.
    :param source: where the data came from (written into the calibration).
    :param words: how the door spells its options (:class:`Words`).
    """

    method: str = 'ml'
    gravity: float = G0
    thermal: str = 'off'
    band_width_c: float = 10.0
    max_predicted_error: float = 0.02
    max_residual_ratio: Optional[float] = 10.0
    max_weight_s: float = MAX_WEIGHT_S
    refuse_unphysical: bool = True
    max_scale_error: float = MAX_SCALE_ERROR
    max_cross_axis: float = MAX_CROSS_AXIS
    max_bias_g: float = MAX_BIAS_G
    allow_unconverged: bool = False
    max_gyro_error: float = DEFAULT_MAX_GYRO_ERROR
    max_mag_error: float = DEFAULT_MAX_MAG_ERROR
    field_uT: Optional[float] = None
    sensor_id: Optional[str] = None
    input_units: Optional[dict] = None
    source: str = ''
    words: Words = FIT

    def replace(self, **changes):
        """Return these settings with ``changes``."""
        return self._replace(**changes)


DEFAULT_SETTINGS = Settings()
"""The defaults every door offers (an option's default, a parameter's)."""
