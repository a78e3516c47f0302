"""Calibrate MEMS triaxial accelerometers and keep their readings corrected (ROS 2)."""

__version__ = '0.1.0'
