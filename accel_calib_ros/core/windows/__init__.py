"""
Static windows: the stretches of a recording where the sensor was held still.

``offline`` finds them in a whole recording (``accel-calib``); ``streaming`` finds the
same ones in a stream, in bounded memory (the calibration node). One window becomes
one observation of the fit.
"""

from .offline import (DEFAULTS, detect_static_windows, distinct_directions, MAX_WEIGHT_S,
                      rotation_rate, StaticWindows, still_mask, still_runs, windows_from_ranges)
from .streaming import OnlineStaticDetector, received_rate

__all__ = ['DEFAULTS', 'MAX_WEIGHT_S', 'OnlineStaticDetector', 'StaticWindows',
           'detect_static_windows', 'distinct_directions', 'received_rate', 'rotation_rate',
           'still_mask', 'still_runs', 'windows_from_ranges']
