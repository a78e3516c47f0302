"""
The recording formats: accepted inputs, the spec's column names, message helpers.

Shared by the CSV reader and writer (``csv_io``), the rosbag2 reader and writer
(``rosbag_io``) and the dispatcher (``recording``).
"""

IMU_TYPE = 'sensor_msgs/msg/Imu'


TEMP_TYPE = 'sensor_msgs/msg/Temperature'


MAG_TYPE = 'sensor_msgs/msg/MagneticField'


ACCEPTED = ('a .csv file, a rosbag2 .mcap or .db3 file, '
            'or a rosbag2 bag directory (holding metadata.yaml)')


REQUIRED_COLUMNS = ('t', 'ax', 'ay', 'az')


GYRO_COLUMNS = ('gx', 'gy', 'gz')


MAG_COLUMNS = ('mx', 'my', 'mz')
"""Magnetic field, µT in the accelerometer frame; all three empty in a row without a sample."""


STANDARD_COLUMNS = REQUIRED_COLUMNS + ('temp',) + GYRO_COLUMNS + MAG_COLUMNS


BAG_SUFFIXES = ('.mcap', '.db3')


MAX_LISTED = 5


def one_line(exc):
    """Return the first line of an exception's message (or its class name)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def listed(items, limit=MAX_LISTED):
    """Format numbers or names as 'a, b, c (and N more)'."""
    items = [str(x) for x in items]
    head = ', '.join(items[:limit])
    if len(items) > limit:
        head += f' (and {len(items) - limit} more)'
    return head
