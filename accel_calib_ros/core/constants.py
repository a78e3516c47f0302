"""
Physical constants and conventions shared by every floor (the one home of each).

Units follow REP-103: m/s², rad/s, tesla on ROS topics; the calibration files and the
science use µT for the magnetic field.
"""

G0 = 9.80665
"""Standard gravity, m/s² (one g: the unit of the accelerometer's full-scale range, of
``--units g`` and of counts per g; the default local gravity)."""

TESLA_PER_UT = 1e-6
"""sensor_msgs/MagneticField carries tesla; files and the science µT."""

AXES = ('x', 'y', 'z')
"""Sensor axes, in the order of every 3-vector."""
