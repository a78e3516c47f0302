"""
The recording formats: accepted inputs, the interface's column names, message helpers.

Shared by the CSV reader and writer (``csv_io``, ``csv_write``), the rosbag2 reader and writer
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


MAX_MESSAGE = 200
"""Longest error line printed, characters (a message quoting a huge input is cut)."""


MAX_WORD = 48
"""A longer word (a path, a quoted cell) is shortened first when a line is too long."""


def _short(word, width=MAX_WORD):
    if len(word) <= width:
        return word
    tail = width // 2
    return word[:width - tail - 1] + '…' + word[-tail:]


def message_line(text, limit=MAX_MESSAGE):
    """
    Return ``text`` as one printable line of at most ``limit`` characters.

    Control, bidi and other invisible characters are shown escaped. A longer text has its
    long words (paths, quoted data) shortened in their middle first, then, if still too
    long, keeps its head and its end (where the advice usually is), joined by `` … ``.
    """
    text = ''.join(c if c.isprintable() else c.encode('unicode_escape').decode('ascii')
                   for c in str(text))
    if len(text) <= limit:
        return text
    text = ' '.join(_short(word) for word in text.split(' '))
    if len(text) <= limit:
        return text
    tail = max(limit // 3, 20)
    return text[:limit - tail - 3] + ' … ' + text[-tail:]
