"""
Static windows: the stretches of a recording where the sensor was held still.

``offline`` finds them in a whole recording (``accel-calib``); ``streaming`` finds the
same ones in a stream, in bounded memory (the calibration node). One window becomes
one observation of the fit. ``streaming`` is imported when it is first asked for (the
commands that read a whole recording do not pay for it at start-up).
"""

from .offline import (DEFAULTS, detect_static_windows, distinct_directions, MAX_WEIGHT_S,
                      rotation_rate, StaticWindows, still_mask, still_runs, windows_from_ranges)

__all__ = ['DEFAULTS', 'MAX_WEIGHT_S', 'OnlineStaticDetector', 'StaticWindows',
           'detect_static_windows', 'distinct_directions', 'received_rate', 'rotation_rate',
           'still_mask', 'still_runs', 'windows_from_ranges']


def __getattr__(name):
    """Import the streaming detector on first use (PEP 562)."""
    if name in ('OnlineStaticDetector', 'received_rate'):
        from . import streaming
        return getattr(streaming, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
