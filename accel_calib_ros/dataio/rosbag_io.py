"""
rosbag2 recordings (MCAP or SQLite 3) of Imu, Temperature and MagneticField messages.

Bag conventions. ``t`` is the Imu ``header.stamp``; when every stamp of a topic is zero
(a driver that never sets it) the bag's receive time is used instead. Temperature is
interpolated in time onto every Imu sample and held constant before the first and after
the last temperature message; it is interpolated on the receive-time axis when the
temperature stamps are all zero. The gyro is ``angular_velocity`` unless every message
marks it unknown (REP-145: ``angular_velocity_covariance[0] == -1``). The magnetic field
(tesla, the accelerometer's frame as the driver publishes it) becomes ``mx my mz`` in µT:
each MagneticField message goes to the Imu sample nearest in time when one lies within
half the Imu sample period (the nearest message wins when several do); the other rows
are NaN (the magnetometer runs slower than the accelerometer).

Bag path convention of ``write_bag`` (what a ROS user expects from the name given):

* ``NAME.mcap`` / ``NAME.db3``: one self-contained storage file at exactly that path.
  rosbag2 embeds its metadata in the storage file, so ``ros2 bag info/play NAME.mcap``
  (Humble and later), Foxglove and ``load_samples`` open it without a ``metadata.yaml``.
  It is written in a hidden temporary bag directory next to the target and renamed into
  place, so an existing file is replaced atomically.
* any other name: a rosbag2 bag directory ``NAME/`` holding ``NAME.mcap`` (or
  ``NAME.db3``) and ``metadata.yaml``, like ``ros2 bag record -o NAME``. Like
  ``ros2 bag record`` it refuses to overwrite an existing directory.

rosbags is imported on first use, so CSV work needs nothing beyond numpy.
"""

import os
from pathlib import Path

import numpy as np

from .atomic import fsync_directory, output_target, replace_into, temp_name
from .formats import ACCEPTED, BAG_SUFFIXES, IMU_TYPE, listed, MAG_TYPE, one_line, TEMP_TYPE
from ..core.constants import TESLA_PER_UT
from ..core.errors import InputError
from ..core.samples import Samples


_STORAGE_SUFFIX = {'mcap': '.mcap', 'sqlite3': '.db3'}


_typestore = None


def _rosbags():
    """
    Import rosbags on first use, so CSV work needs nothing beyond numpy.

    On a robot built with colcon, rosbags is not a rosdep key: ``pip install rosbags``.
    """
    try:
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError:
        raise InputError('reading or writing rosbag2 files needs the rosbags package: '
                         'pip install rosbags') from None
    return rosbags.rosbag2, rosbags.typesys


def _types():
    """Return the ROS 2 Jazzy type store (built once, on first use)."""
    global _typestore
    if _typestore is None:
        typesys = _rosbags()[1]
        _typestore = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    return _typestore


def _bag_source(path):
    """
    Return what to hand to the rosbags Reader for ``path``.

    A directory must hold ``metadata.yaml``; a directory without it but with exactly one
    storage file (metadata lost) is read through that file.
    """
    if not path.is_dir():
        return path
    if (path / 'metadata.yaml').is_file():
        return path
    storage = sorted(p for p in path.iterdir() if p.suffix.lower() in BAG_SUFFIXES)
    if len(storage) == 1:
        return storage[0]
    detail = (f'and {len(storage)} storage files' if storage
              else 'and no .mcap or .db3 storage file')
    raise InputError(f'{path}: not a rosbag2 bag directory: no metadata.yaml {detail}; '
                     f'expected {ACCEPTED}')


def _normalize_topic(name):
    """Return a topic name in the absolute form rosbag2 records ('imu' -> '/imu')."""
    name = name.strip()
    return name if name.startswith('/') else '/' + name


def _topic_types(connections):
    """Map each topic to the set of message types recorded on it."""
    types = {}
    for c in connections:
        types.setdefault(c.topic, set()).add(c.msgtype)
    return types


def _pick_topic(types, msgtype, wanted, path, option):
    """
    Return the topic of ``msgtype`` to read: ``wanted`` if given, else the only one.

    :return: the topic name, or None when no topic has the type and none was asked for.
    """
    candidates = sorted(t for t, ts in types.items() if msgtype in ts)
    short = msgtype.replace('/msg/', '/')
    if wanted is not None:
        topic = _normalize_topic(wanted)
        if topic not in types:
            have = listed(candidates) if candidates else 'none'
            raise InputError(f'{path}: topic {topic} is not in the bag ({short} topics: '
                             f'{have})')
        if msgtype not in types[topic]:
            raise InputError(f'{path}: topic {topic} carries '
                             f'{", ".join(sorted(types[topic]))}, not {short}')
        return topic
    if len(candidates) > 1:
        raise InputError(f'{path}: several {short} topics ({", ".join(candidates)}); '
                         f'choose one with {option}')
    return candidates[0] if candidates else None


def _namespace(topic):
    """Return the namespace of a topic ('/imu/data_raw' -> '/imu')."""
    return topic.rsplit('/', 1)[0]


# Imu and Temperature end in a fixed block of float64 after the variable-length frame_id:
# Imu: orientation (4), its covariance (9), angular_velocity (3), covariance (9),
# linear_acceleration (3), covariance (9); Temperature: temperature, variance.
# MagneticField: magnetic_field (3), its covariance (9).
_TAIL_DOUBLES = {IMU_TYPE: 37, TEMP_TYPE: 2, MAG_TYPE: 12}


_IMU_COLUMNS = [25, 26, 27, 13, 14, 15, 16]  # accel xyz, gyro xyz, gyro covariance[0]


_TEMP_COLUMNS = [0]


_MAG_COLUMNS = [0, 1, 2]


_CDR_LE = b'\x00\x01'


def _decode_fast(raws, msgtype):
    """
    Decode little-endian CDR messages of one length with numpy, in one go.

    Layout after the 4-byte encapsulation header: stamp sec (int32), nanosec (uint32),
    frame_id length (uint32, with the NUL) and bytes, padding to 8, then the doubles.

    :return: (stamps ns, (N, k) doubles), or None when the batch does not fit the layout.
    """
    size = len(raws[0])
    tail = 8 * _TAIL_DOUBLES[msgtype]
    start = size - tail  # offset of the doubles in the raw message
    if start < 16 or (start - 4) % 8 or any(len(r) != size for r in raws):
        return None
    buf = np.frombuffer(b''.join(raws), dtype=np.uint8).reshape(len(raws), size)
    if np.any(buf[:, 0] != 0) or np.any(buf[:, 1] != 1):
        return None  # not little-endian plain CDR
    head = np.ascontiguousarray(buf[:, 4:16]).view('<u4')
    string_end = 16 + head[:, 2].astype(np.int64)
    if np.any(string_end > start) or np.any(start - string_end >= 8):
        return None  # the frame_id length does not lead to this padding
    stamps = head[:, 0].view('<i4').astype(np.int64) * 1_000_000_000 + head[:, 1]
    doubles = np.ascontiguousarray(buf[:, start:]).view('<f8')
    return stamps, doubles


def _decode_slow(raws, msgtype):
    """Decode messages one by one with rosbags (any layout, any byte order)."""
    deserialize = _types().deserialize_cdr
    stamps, rows = [], []
    for raw in raws:
        msg = deserialize(raw, msgtype)
        stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        if msgtype == IMU_TYPE:
            q, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
            rows.append([q.x, q.y, q.z, q.w, *msg.orientation_covariance,
                         w.x, w.y, w.z, *msg.angular_velocity_covariance,
                         a.x, a.y, a.z, *msg.linear_acceleration_covariance])
        elif msgtype == MAG_TYPE:
            m = msg.magnetic_field
            rows.append([m.x, m.y, m.z, *msg.magnetic_field_covariance])
        else:
            rows.append([msg.temperature, msg.variance])
    return (np.asarray(stamps, dtype=np.int64),
            np.asarray(rows, dtype=float).reshape(len(rows), _TAIL_DOUBLES[msgtype]))


def _read_topic(reader, topic, msgtype, columns):
    """
    Read every message of one topic.

    :return: (receive times ns, header stamps ns, (N, len(columns)) selected doubles).
    """
    connections = [c for c in reader.connections if c.topic == topic and c.msgtype == msgtype]
    received, raws = [], []
    for _, timestamp, raw in reader.messages(connections=connections):
        received.append(timestamp)
        raws.append(raw)
    received = np.asarray(received, dtype=np.int64)
    if not raws:
        return received, np.zeros(0, dtype=np.int64), np.zeros((0, len(columns)))
    decoded = _decode_fast(raws, msgtype) or _decode_slow(raws, msgtype)
    stamps, doubles = decoded
    return received, stamps, doubles[:, columns]


def _time_axis(received, stamps):
    """Choose header stamps, or receive times when the stamps were never set."""
    use_stamps = bool(np.any(stamps != 0))
    return (stamps if use_stamps else received), use_stamps


def _pick_near(types, msgtype, wanted, imu, path, option):
    """Pick a topic like ``_pick_topic``; several without a choice: the one beside ``imu``."""
    if wanted is None:
        topics = sorted(t for t, ts in types.items() if msgtype in ts)
        near = [t for t in topics if _namespace(t) == _namespace(imu)]
        if len(topics) > 1 and len(near) == 1:
            wanted = near[0]
    return _pick_topic(types, msgtype, wanted, path, option)


def _match_mag(reader, topic, imu_time, received, explicit, path):
    """
    Return the field (N, 3) µT at each Imu sample: the nearest message within half a period.

    :param imu_time: (N,) the Imu samples' time axis, ns (stamps, or receive times when the
        stamps were never set); ``received`` their receive times, ns.
    :param explicit: the topic was asked for (an empty one is then an error).
    """
    m_received, m_stamps, values = _read_topic(reader, topic, MAG_TYPE, _MAG_COLUMNS)
    if not len(values):
        if explicit:
            raise InputError(f'{path}: topic {topic} holds no messages')
        return None
    x, use_stamps = _time_axis(m_received, m_stamps)
    at = (imu_time if use_stamps else received).astype(np.int64)
    mag = np.full((len(at), 3), np.nan)
    if len(at) > 1:
        half = 0.5 * float(np.median(np.diff(at)))
    else:
        half = float('inf')
    i = np.clip(np.searchsorted(at, x), 1, max(len(at) - 1, 1))
    if len(at) > 1:
        i = np.where(np.abs(x - at[i - 1]) <= np.abs(at[i] - x), i - 1, i)
    else:
        i = np.zeros(len(x), np.int64)
    distance = np.abs((x - at[i]).astype(float))
    ok = (distance <= half) & np.all(np.isfinite(values), axis=1)
    order = np.argsort(-distance[ok], kind='stable')    # the nearest is written last
    mag[i[ok][order]] = values[ok][order] / TESLA_PER_UT
    return mag


def load_bag(path, imu_topic, temp_topic, mag_topic=None):
    """Read Imu (and Temperature, MagneticField) messages from a rosbag2 recording."""
    source = _bag_source(path)
    rosbag2 = _rosbags()[0]
    try:
        reader = rosbag2.Reader(source)
        reader.open()
    except Exception as exc:  # rosbags raises assorted errors on foreign or corrupt files
        raise InputError(f'{path}: not a readable rosbag2 recording ({one_line(exc)}); '
                         f'expected {ACCEPTED}') from None
    try:
        types = _topic_types(reader.connections)
        imu = _pick_topic(types, IMU_TYPE, imu_topic, path, '--imu-topic')
        if imu is None:
            listing = ', '.join(f'{t} ({"/".join(sorted(ts))})' for t, ts in sorted(types.items()))
            raise InputError(f'{path}: no sensor_msgs/Imu topic in the bag '
                             f'(topics: {listing or "none"})')
        temp = temp_topic
        if temp is None:
            temps = sorted(t for t, ts in types.items() if TEMP_TYPE in ts)
            near = [t for t in temps if _namespace(t) == _namespace(imu)]
            if len(temps) > 1 and len(near) == 1:
                temp = near[0]
        temp = _pick_topic(types, TEMP_TYPE, temp, path, '--temp-topic')

        received, stamps, data = _read_topic(reader, imu, IMU_TYPE, _IMU_COLUMNS)
        if not len(data):
            raise InputError(f'{path}: topic {imu} holds no messages')
        imu_time, _ = _time_axis(received, stamps)
        order = np.argsort(imu_time, kind='stable')
        data = data[order]
        imu_time, received = imu_time[order], received[order]
        t = imu_time * 1e-9
        accel = data[:, 0:3]
        gyro = None if np.all(data[:, 6] == -1.0) else data[:, 3:6]

        temperature = None
        if temp is not None:
            t_received, t_stamps, values = _read_topic(reader, temp, TEMP_TYPE, _TEMP_COLUMNS)
            if not len(values) and temp_topic is not None:
                raise InputError(f'{path}: topic {temp} holds no messages')
            if len(values):
                x, use_stamps = _time_axis(t_received, t_stamps)
                at = imu_time if use_stamps else received
                order = np.argsort(x, kind='stable')
                temperature = np.interp(at.astype(float), x[order].astype(float),
                                        values[order, 0])
        mag_name = _pick_near(types, MAG_TYPE, mag_topic, imu, path, '--mag-topic')
        mag = None
        if mag_name is not None:
            mag = _match_mag(reader, mag_name, imu_time, received, mag_topic is not None, path)
    except InputError:
        raise
    except Exception as exc:  # corrupt chunks or messages surface as assorted errors
        raise InputError(f'{path}: cannot read the bag ({one_line(exc)})') from None
    finally:
        reader.close()
    return Samples(t, accel, temperature, gyro, mag)


def _storage_for(path, storage):
    """Return the rosbags storage plugin name for ``path`` and an optional explicit choice."""
    suffix = Path(path).suffix.lower()
    implied = {'.db3': 'sqlite3', '.mcap': 'mcap'}.get(suffix)
    if storage is None:
        return implied or 'mcap'
    if storage not in _STORAGE_SUFFIX:
        raise InputError(f'unknown bag storage {storage!r}; use mcap or sqlite3')
    if implied and implied != storage:
        raise InputError(f'{path}: a {suffix} file cannot hold {storage} storage')
    return storage


def _serialized_batch(msgtype, frame_id, ns, doubles):
    """
    Serialize one message per row: a rosbags-made template with stamps and doubles filled in.

    Only the numeric fields at the fixed offsets of ``_decode_fast`` are overwritten, so
    the byte layout (encapsulation header, frame_id string, padding) is rosbags' own.

    :param msgtype: IMU_TYPE, TEMP_TYPE or MAG_TYPE.
    :param frame_id: header.frame_id of every message.
    :param ns: (N,) stamps, integer nanoseconds.
    :param doubles: (N, _TAIL_DOUBLES[msgtype]) values of the float64 tail.
    :return: (N, size) uint8 array, one serialized message per row.
    """
    ts = _types()
    header = ts.types['std_msgs/msg/Header'](
        stamp=ts.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id=frame_id)
    if msgtype == IMU_TYPE:
        vector = ts.types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
        template = ts.types[IMU_TYPE](
            header=header,
            orientation=ts.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9), angular_velocity=vector,
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vector,
            linear_acceleration_covariance=np.zeros(9))
    elif msgtype == MAG_TYPE:
        template = ts.types[MAG_TYPE](
            header=header,
            magnetic_field=ts.types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
            magnetic_field_covariance=np.zeros(9))
    else:
        template = ts.types[TEMP_TYPE](header=header, temperature=0.0, variance=0.0)
    raw = np.frombuffer(bytes(ts.serialize_cdr(template, msgtype)), dtype=np.uint8)
    start = len(raw) - 8 * _TAIL_DOUBLES[msgtype]
    buf = np.tile(raw, (len(ns), 1))
    stamps = np.empty((len(ns), 2), dtype='<u4')
    stamps[:, 0] = ns // 1_000_000_000
    stamps[:, 1] = ns % 1_000_000_000
    buf[:, 4:12] = stamps.view(np.uint8).reshape(len(ns), 8)
    buf[:, start:] = np.ascontiguousarray(doubles, dtype='<f8').view(np.uint8).reshape(
        len(ns), -1)
    return buf


def _mag_batch(samples, frame_id, ns):
    """
    Serialize the rows holding a magnetometer sample as MagneticField messages (tesla).

    :returns: (row indices, messages) or None without a magnetometer.
    """
    if samples.mag is None:
        return None
    rows = np.flatnonzero(samples.mag_rows)
    doubles = np.zeros((len(rows), _TAIL_DOUBLES[MAG_TYPE]))   # covariance 0: unknown
    doubles[:, :3] = samples.mag[rows] * TESLA_PER_UT
    return rows, _serialized_batch(MAG_TYPE, frame_id, ns[rows], doubles)


def _bag_batches(samples, frame_id):
    """Serialize one piece of Samples: (stamps ns, Imu messages, Temperature messages)."""
    n = len(samples)
    ns = np.round(samples.t * 1e9).astype(np.int64)
    imu = np.zeros((n, _TAIL_DOUBLES[IMU_TYPE]))
    imu[:, 3] = 1.0  # identity orientation quaternion ...
    imu[:, 4] = -1.0  # ... marked unknown (REP-145: covariance[0] = -1)
    if samples.gyro is None:
        imu[:, 16] = -1.0  # no angular velocity either
    else:
        imu[:, 13:16] = samples.gyro
    imu[:, 25:28] = samples.accel  # its covariance stays all zeros: "unknown"
    imu_raw = _serialized_batch(IMU_TYPE, frame_id, ns, imu)
    temp_raw = None
    if samples.temp is not None:
        temp_raw = _serialized_batch(TEMP_TYPE, frame_id, ns,
                                     np.column_stack([samples.temp, np.zeros(n)]))
    return ns, imu_raw, temp_raw


def _write_bag_dir(bagdir, pieces, imu_topic, temp_topic, frame_id, storage,
                   mag_topic='/imu/mag'):
    """Write the rosbag2 directory ``bagdir`` (must not exist) from Samples pieces."""
    ts = _types()
    rosbag2 = _rosbags()[0]
    plugins = rosbag2.StoragePlugin
    plugin = plugins.SQLITE3 if storage == 'sqlite3' else plugins.MCAP
    with rosbag2.Writer(bagdir, version=rosbag2.Writer.VERSION_LATEST,
                        storage_plugin=plugin) as writer:
        imu_conn = temp_conn = mag_conn = None
        for samples in pieces:
            ns, imu_raw, temp_raw = _bag_batches(samples, frame_id)
            mag = _mag_batch(samples, frame_id, ns)
            if imu_conn is None:
                imu_conn = writer.add_connection(imu_topic, IMU_TYPE, typestore=ts)
                if temp_raw is not None:
                    temp_conn = writer.add_connection(temp_topic, TEMP_TYPE, typestore=ts)
                if mag is not None:
                    mag_conn = writer.add_connection(mag_topic, MAG_TYPE, typestore=ts)
            mag_at = {} if mag is None else dict(zip(mag[0].tolist(), range(len(mag[0]))))
            for i, stamp in enumerate(ns.tolist()):
                writer.write(imu_conn, stamp, imu_raw[i].tobytes())
                if temp_conn is not None:
                    writer.write(temp_conn, stamp, temp_raw[i].tobytes())
                if i in mag_at:
                    writer.write(mag_conn, stamp, mag[1][mag_at[i]].tobytes())


def _checked_pieces(first, rest):
    """Yield ``first`` then ``rest``: validated, times in order, the same columns in each."""
    yield first
    t_last = first.t[-1]
    for piece in rest:
        piece.validate()
        if (piece.temp is None) != (first.temp is None) or \
                (piece.gyro is None) != (first.gyro is None):
            raise InputError('samples written to one bag must all have (or lack) temp and gyro')
        if (piece.mag is None) != (first.mag is None):
            raise InputError('samples written to one bag must all have (or lack) mx my mz')
        if piece.t[0] < t_last:
            raise InputError('bag samples must be in increasing time order')
        t_last = piece.t[-1]
        yield piece


def _fsync_tree(directory):
    """Flush every file of a freshly written directory to disk."""
    for entry in os.scandir(directory):
        if entry.is_file():
            fd = os.open(entry.path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    fsync_directory(directory)


def _scratch_folder(parent, name):
    """Make a private hidden folder next to the target (its name fits in NAME_MAX)."""
    for _ in range(100):
        scratch = parent / temp_name(str(parent), name, os.urandom(4).hex())
        try:
            scratch.mkdir(mode=0o700)
        except FileExistsError:
            continue
        return scratch
    raise FileExistsError(f'could not create a temporary folder in {parent}')


def write_bag(path, samples, imu_topic='/imu/data_raw', temp_topic='/imu/temperature',
              frame_id='imu_link', storage=None, mag_topic='/imu/mag'):
    """
    Write samples as a rosbag2 recording of Imu (and Temperature) messages.

    ``path`` ending in ``.mcap`` / ``.db3`` gives one self-contained storage file at that
    path, replaced atomically; any other path gives a bag directory ``path/`` with
    ``metadata.yaml``, as ``ros2 bag record -o path`` would (see the module docstring).
    Header stamps and receive times are both ``t``; orientation is marked unknown and, when
    the samples have no gyro, so is the angular velocity (REP-145). The temperature, when
    present, is published on ``temp_topic`` with the same stamp as each Imu message; the
    magnetic field, when present, as sensor_msgs/MagneticField (tesla, covariance
    unknown) on ``mag_topic`` with the stamp of its row, for the rows holding a sample.

    :param path: output file (``.mcap``/``.db3``) or bag directory.
    :param samples: the Samples to write (t in seconds, t >= 0), or an iterable of Samples
        pieces in time order (written in turn, in bounded memory).
    :param imu_topic: topic of the ``sensor_msgs/msg/Imu`` messages.
    :param temp_topic: topic of the ``sensor_msgs/msg/Temperature`` messages.
    :param frame_id: ``header.frame_id`` of every message.
    :param storage: 'mcap' or 'sqlite3'; default from the suffix (.db3 -> sqlite3, else mcap).
    :param mag_topic: topic of the ``sensor_msgs/msg/MagneticField`` messages.
    :return: the Path written (the file or the bag directory).
    :raises InputError: bad samples or arguments, an existing bag directory, or the
        location cannot be written.
    """
    target = Path(path)
    storage = _storage_for(target, storage)
    rest = iter(())
    if not isinstance(samples, Samples):
        rest = iter(samples)
        samples = next(rest, None)
        if samples is None:
            raise InputError('no samples: the recording is empty')
    samples.validate()
    if samples.t[0] < 0:
        raise InputError('bag times must not be negative (t starts at '
                         f'{samples.t[0]:.9g} s); shift t to start at zero or later')
    imu_topic = _normalize_topic(imu_topic)
    temp_topic = _normalize_topic(temp_topic)
    if samples.temp is not None and temp_topic == imu_topic:
        raise InputError(f'the Imu and Temperature topics must differ (both {imu_topic})')
    mag_topic = _normalize_topic(mag_topic)
    if samples.mag is not None and mag_topic in (imu_topic, temp_topic):
        raise InputError(f'the MagneticField topic must differ from the others ({mag_topic})')
    single_file = target.suffix.lower() in BAG_SUFFIXES
    if not single_file and os.path.lexists(target):
        raise InputError(f'{target} exists already; a rosbag2 directory is never overwritten, '
                         f'choose a new name')
    real = Path(output_target(target, folder=not single_file))   # no foreign link, no device
    parent = real.parent
    if not parent.is_dir():
        raise InputError(f'{target}: output directory {parent} does not exist')
    name = target.stem if single_file else target.name
    try:
        scratch = _scratch_folder(parent, name)
    except OSError as exc:
        raise InputError(f'{target}: cannot write ({exc.strerror or one_line(exc)})') from None
    try:
        bagdir = scratch / name
        _write_bag_dir(bagdir, _checked_pieces(samples, rest), imu_topic, temp_topic,
                       frame_id, storage, mag_topic)
        _fsync_tree(bagdir)
        if single_file:
            replace_into(bagdir / f'{name}{_STORAGE_SUFFIX[storage]}', str(real))
        else:
            os.rename(bagdir, real)
            fsync_directory(str(parent))
    except OSError as exc:
        raise InputError(f'{target}: cannot write ({exc.strerror or one_line(exc)})') from None
    finally:
        import shutil
        shutil.rmtree(scratch, ignore_errors=True)
    return target
