"""Exceptions raised by the calibration core."""


class CalibrationError(Exception):
    """
    A calibration cannot be solved from the data given (CLI exit status 1).

    The message says why and what to record instead.
    """


class InputError(ValueError):
    """The input data are malformed (CLI exit status 2)."""
