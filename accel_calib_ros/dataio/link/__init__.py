"""
The serial link apart from any ROS node: the transport half of the driver.

- :mod:`.serial_link`: :class:`SerialLink`, a supervised reader thread that opens the
  port (with back-off), watches it, asks the firmware for its info frame, parses and
  stamps the frames and hands them to callbacks; clock and port are injected, so the
  link runs the same on a real port, on a pty and on a fake port with a fake clock;
- :mod:`.link_health`: :func:`assess`, the pure link-health assessment (level, message and
  the values of one ``/diagnostics`` period) from two snapshots of the link.
"""

from .link_health import assess, ERROR, link_values, OK, WARN
from .serial_link import open_serial, READ_TIMEOUT_S, SerialLink, SystemClock

__all__ = ['assess', 'ERROR', 'link_values', 'OK', 'open_serial', 'READ_TIMEOUT_S',
           'SerialLink', 'SystemClock', 'WARN']
