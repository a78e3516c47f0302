"""
Read and write recordings: the interface's CSV and rosbag2 (MCAP or SQLite 3) bags, as ``Samples``.

``load_samples`` (whole recording, validated) and ``iter_samples`` (pieces, for streaming
commands) accept

* a ``.csv`` file (interface.md §2): a header row; required columns ``t``,
  ``ax``, ``ay``, ``az``; optional ``temp``, ``gx``, ``gy``, ``gz`` and ``mx``, ``my``,
  ``mz`` (µT, empty in rows without a magnetometer sample); other columns are ignored;
  names are matched case-insensitively after stripping spaces (``csv_io``);
* a rosbag2 recording of ``sensor_msgs/msg/Imu`` (plus ``sensor_msgs/msg/Temperature`` and
  ``sensor_msgs/msg/MagneticField`` if recorded), given as the bag directory (the one
  holding ``metadata.yaml``, what ``ros2 bag record -o NAME`` creates), as a ``.mcap`` /
  ``.db3`` storage file inside such a directory, or as a bare storage file without
  ``metadata.yaml`` (``rosbag_io``).

Writers: ``csv_write.write_samples_csv`` / ``csv_write.csv_writer`` and ``rosbag_io.write_bag``.
Every malformed input raises ``InputError`` with a one-line message that says what is
wrong and where (file, line, topic), so the CLI can print it and exit with status 2.
"""

from pathlib import Path

from .csv_io import iter_csv, load_csv, PARSE_CHUNK_ROWS
from .csv_write import csv_writer, write_samples_csv
from .formats import ACCEPTED, BAG_SUFFIXES
from .rosbag_io import load_bag, write_bag
from ..core.errors import InputError

__all__ = ['csv_writer', 'iter_samples', 'load_samples', 'write_bag', 'write_samples_csv']


def _bag_time_unit(time_unit):
    """Refuse a time unit other than seconds for a bag (its stamps are converted already)."""
    if time_unit not in (None, 's'):
        raise InputError(f'--time-unit {str(time_unit)[:20]} applies to CSV files only: rosbag2 '
                         'stamps are nanoseconds, read as seconds already')


def load_samples(path, imu_topic=None, temp_topic=None, on_read=None, time_unit='s',
                 mag_topic=None):
    """
    Load a recording as validated ``Samples``.

    :param path: a ``.csv`` file, a ``.mcap`` / ``.db3`` file or a rosbag2 directory.
    :param imu_topic: bags only: the ``sensor_msgs/msg/Imu`` topic (needed if several).
    :param temp_topic: bags only: the ``sensor_msgs/msg/Temperature`` topic (needed if
        several and none shares the Imu topic's namespace).
    :param on_read: CSV only: called with the characters read after each block (progress).
    :param time_unit: CSV only: unit of the ``t`` column ('s', 'ms', 'us', 'ns'); a
        spacing no IMU has is refused (``time_units.check_time_spacing``).
    :param mag_topic: bags only: the ``sensor_msgs/msg/MagneticField`` topic (default: the
        only one, or the one beside the Imu topic).
    :return: Samples with t, accel and, when recorded, temp, gyro and mag.
    :raises InputError: the path is missing, of an unknown kind or malformed.
    """
    p = Path(path)
    if not p.exists():
        if p.is_symlink():
            raise InputError(f'{p}: broken symbolic link')
        raise InputError(f'{p}: no such file or directory')
    suffix = p.suffix.lower()
    if p.is_dir():
        _bag_time_unit(time_unit)
        samples = load_bag(p, imu_topic, temp_topic, mag_topic)
    elif suffix == '.csv':
        samples = load_csv(p, on_read, time_unit or 's')
    elif suffix in BAG_SUFFIXES:
        _bag_time_unit(time_unit)
        samples = load_bag(p, imu_topic, temp_topic, mag_topic)
    else:
        raise InputError(f'{p}: unsupported data file {suffix or "(no suffix)"}; '
                         f'expected {ACCEPTED}')
    try:
        return samples.validate()
    except InputError as exc:
        raise InputError(f'{p}: {exc}') from None


def iter_samples(path, chunk_rows=PARSE_CHUNK_ROWS, imu_topic=None, temp_topic=None, on_read=None,
                 time_unit='s', mag_topic=None, non_finite='refuse'):
    """
    Load a recording piece by piece: a generator of validated ``Samples``.

    A CSV file is read ``chunk_rows`` data lines at a time, so a file of any length is
    handled in bounded memory; problems are reported as by ``load_samples`` (a bad row
    in a later piece raises when that piece is reached). A bag is loaded whole, then
    handed out in pieces.

    :param path: as for ``load_samples``.
    :param chunk_rows: data rows per piece.
    :param imu_topic: bags only, as for ``load_samples``.
    :param temp_topic: bags only, as for ``load_samples``.
    :param on_read: CSV only: called with the characters read for each piece (progress).
    :param time_unit: CSV only, as for ``load_samples``.
    :param mag_topic: bags only, as for ``load_samples``.
    :param non_finite: CSV only: 'refuse', or 'keep' NaN, infinite and empty cells as NaN
        (for a reader that skips such rows itself, as ``accel-calib health`` does).
    :return: generator of Samples, in time order.
    :raises InputError: as ``load_samples``.
    """
    p = Path(path)
    if p.suffix.lower() == '.csv' and p.is_file():
        for piece in iter_csv(p, chunk_rows, on_read, time_unit or 's', non_finite):
            if non_finite == 'keep':
                yield piece
                continue
            try:
                yield piece.validate()
            except InputError as exc:
                raise InputError(f'{p}: {exc}') from None
        return
    whole = load_samples(path, imu_topic=imu_topic, temp_topic=temp_topic, time_unit=time_unit,
                         mag_topic=mag_topic)
    for a in range(0, len(whole), chunk_rows):
        yield whole.subset(slice(a, a + chunk_rows))
