"""
Former home of the wire format, now the package :mod:`accel_calib_ros.dataio.wire`.

Kept as an alias so that code written against the old module keeps working while other
branches are merged; new code imports from :mod:`accel_calib_ros.dataio.wire`.
"""

from .wire import *  # noqa: F401,F403
from .wire import __all__  # noqa: F401
