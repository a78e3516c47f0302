"""
The parameters of the ``accel_calibration`` node: each described once, typed and ranged.

``nodes.parameters.declare_parameters`` declares them with their descriptors and checks
every start-up value and runtime change; the check that spans a value's meaning (a sample
rate that is an IMU's) lives here too (a sensor id's: ``paths.sensor_param``).
"""

from .calibration_thermal import THERMAL_PARAMS
from .parameters import Param, ParameterProblem
from ..core.collector import DEFAULT_MAX_MAG_SAMPLES, DEFAULT_MAX_SAMPLES
from ..core.windows import DEFAULTS
from ..session.settings import DEFAULT_SETTINGS as S, LIVE_METHODS, THERMAL_MODES

MIN_RATE_HZ = 1.0
"""Lowest nonzero ``rate_hz`` accepted, Hz (an IMU below 1 Hz is a unit mistake)."""


def _detector_param(name, description):
    return Param(name, 0.0, description + f' (0 = as accel-calib fit: {DEFAULTS[name]:g} s)'
                 if name.endswith('_s') else description
                 + f' (0 = as accel-calib fit: {DEFAULTS[name]:g})', low=0.0, high=60.0)


PARAMS = [
    Param('method', S.method, 'solver: ml (Sun & Xu, 9 parameters), gn (6 parameters) or '
          'ml-bc', choices=LIVE_METHODS),
    Param('frame_id', 'imu_link',
          "the sensor's frame_id (the driver's): with the namespace it names the sensor "
          '(sensor_id) and its default files', empty_ok=False),
    Param('calibration_file', '',
          "YAML file written by ~/calibrate ('' = $ROS_HOME/accel_calib_ros/<sensor_id>/"
          'calibration.yaml); its directory is created'),
    Param('gravity', S.gravity, 'local gravity magnitude, m/s2', low=9.7, high=9.9),
    Param('band_width_c', S.band_width_c, 'width of a temperature band, degC', low=0.1,
          high=100.0),
    Param('thermal', 'auto',
          'auto: temperature-band tables when >= 2 bands are filled; on; off',
          choices=THERMAL_MODES),
    Param('max_residual_ratio', S.max_residual_ratio,
          'refuse when the gravity-norm residual RMS exceeds this x window-mean noise',
          low=1.0),
    Param('max_scale_error', S.max_scale_error, 'refuse when |T_ii - 1| exceeds this', low=0.0,
          low_open=True, high=1.0),
    Param('max_cross_axis', S.max_cross_axis, 'refuse when |T_ij| / T_ii exceeds this', low=0.0,
          low_open=True, high=1.0),
    Param('max_bias_g', S.max_bias_g, 'refuse when a bias exceeds this many g', low=0.0,
          low_open=True, high=2.0),
    Param('max_predicted_error', S.max_predicted_error,
          'refuse when the predicted accuracy (RMS error at 1 g over all orientations) '
          'exceeds this, m/s2', low=0.0, low_open=True, high=10.0),
    Param('target_accuracy', 0.01,
          'predicted accuracy that is enough: the advice says "enough" below it, m/s2',
          low=0.0, low_open=True, high=10.0),
    _detector_param('window_s', 'moving standard deviation window, s'),
    _detector_param('min_duration_s', 'shortest static window kept after trimming, s'),
    _detector_param('trim_s', 'cut from each end of a still stretch, s'),
    _detector_param('threshold_factor', 'still when moving std < factor x noise floor'),
    Param('use_gyro', True, 'the angular rate must be still too (when the driver sends it)'),
    Param('max_windows', 500, 'windows kept; the oldest are dropped beyond', low=10,
          high=100000),
    Param('max_weight_s', S.max_weight_s, 'a window weighs at most this many seconds of samples',
          low=1e-3, high=3600.0),
    Param('rate_hz', 0.0,
          'sample rate to start with, Hz: 0 (measure it from the stamps; always tracked) '
          f'or {MIN_RATE_HZ:g} .. 100000', low=0.0, high=100000.0),
    Param('sensor_id', '',
          'the sensor the calibration is made for, recorded in the file and the history '
          "('' = namespace/frame_id, e.g. robot1/imu_link); printable, surrounding spaces "
          'dropped'),
    Param('history', True,
          'record each saved calibration and its windows in the history database'),
    Param('history_file', '',
          "history database ('' = history.sqlite beside calibration_file)"),
    Param('max_gyro_samples', DEFAULT_MAX_SAMPLES,
          'raw samples kept for the gyroscope scale/misalignment fit (36 bytes each; the '
          'moves between the windows still kept are used; 0 = no gyro T)', low=0,
          high=10_000_000, read_only=True),
    Param('max_mag_samples', DEFAULT_MAX_MAG_SAMPLES,
          'imu/mag samples kept for the magnetometer fit (decimated by 2 whenever full; '
          '0 = no magnetometer calibration)', low=0, high=1_000_000, read_only=True),
    Param('max_gyro_error', S.max_gyro_error,
          'store the gyro scale/misalignment only when its predicted accuracy (RMS '
          'relative rate error over all directions) is at most this', low=0.0,
          low_open=True, high=1.0),
    Param('max_mag_error', S.max_mag_error,
          'store the magnetometer calibration only when its predicted accuracy (RMS field '
          'error over all directions) is at most this, uT', low=0.0, low_open=True,
          high=1000.0),
    Param('field_uT', 0.0,
          'known local magnetic field magnitude, uT (0 = fitted, trusting the '
          'magnetometer sensitivity on average)', low=0.0, high=1000.0),
] + THERMAL_PARAMS


def check_rate(rate_hz):
    """Refuse a starting rate that is neither 0 (measure it) nor an IMU's."""
    if rate_hz and rate_hz < MIN_RATE_HZ:
        raise ParameterProblem(f"parameter 'rate_hz' must be 0 or >= {MIN_RATE_HZ:g} Hz, got "
                               f'{rate_hz!r}')
