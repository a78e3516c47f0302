"""
The accelerometer's calibration: T (scale and non-orthogonality) and bias.

``ml`` (Sun & Xu 2020, maximum likelihood with Newton iteration), ``gn`` (Gui Yi's
six-parameter Gauss-Newton), ``ellipsoid`` (algebraic least squares, the start of the
others), ``thermal`` (temperature-band tables) and ``fit`` (``calibrate``: the fit of a
session's windows, its covariance and outlier windows).
"""
