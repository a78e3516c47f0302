"""ROS-free calibration science: numpy and scipy only, importable anywhere."""

from .calibration import calibrate, Calibration, METHODS
from .errors import CalibrationError, InputError
from .samples import Samples
from .windows import detect_static_windows, StaticWindows

__all__ = ['calibrate', 'Calibration', 'CalibrationError', 'InputError', 'METHODS',
           'Samples', 'detect_static_windows', 'StaticWindows']
