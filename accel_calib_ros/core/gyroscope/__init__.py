"""
The gyroscope's calibration: zero-rate bias, scale and misalignment (interface.md §6, §9).

``fit`` fits T from the moves between the static windows (imu_tk's method), with the
bias from the windows; ``moves`` integrates the rotations of those moves.
"""
