"""Tests for reading and writing recordings (CSV, rosbag2) and atomic file writes."""

import os
import time

from accel_calib_ros.core.errors import InputError
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio import atomic, csv_io, rosbag_io
from accel_calib_ros.dataio.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from accel_calib_ros.dataio.recording import load_samples, write_bag, write_samples_csv
import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores

TS = get_typestore(Stores.ROS2_JAZZY)


def make_samples(n=200, temp=True, gyro=True, t0=0.0, seed=0):
    """Return random but plausible samples."""
    rng = np.random.default_rng(seed)
    return Samples(t0 + np.arange(n) * 0.01,
                   rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 9.8]),
                   20.0 + np.linspace(0.0, 5.0, n) if temp else None,
                   rng.normal(scale=0.01, size=(n, 3)) if gyro else None)


def assert_same(a, b, rtol=1e-8, atol=1e-9):
    """
    Assert two Samples match (to the CSV's printed precision by default).

    Times agree to 1 µs: float64 seconds near 1.7e9 (epoch stamps) resolve 0.24 µs.
    """
    assert len(a) == len(b)
    np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-6)
    np.testing.assert_allclose(a.accel, b.accel, rtol=rtol, atol=atol)
    for x, y in ((a.temp, b.temp), (a.gyro, b.gyro)):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_allclose(x, y, rtol=rtol, atol=atol)


def write_text(path, text):
    """Write a test file and return its path."""
    path.write_text(text)
    return path


def bad(path, *words, **kwargs):
    """Assert load_samples raises a one-line InputError containing every word."""
    with pytest.raises(InputError) as info:
        load_samples(path, **kwargs)
    message = str(info.value)
    assert '\n' not in message
    for word in words:
        assert word.lower() in message.lower(), message
    return message


def imu_msg(stamp_ns, accel, frame='imu'):
    """Return a serialized Imu message."""
    Imu = TS.types['sensor_msgs/msg/Imu']  # noqa: N806
    Header = TS.types['std_msgs/msg/Header']  # noqa: N806
    Time = TS.types['builtin_interfaces/msg/Time']  # noqa: N806
    Vector3 = TS.types['geometry_msgs/msg/Vector3']  # noqa: N806
    Quaternion = TS.types['geometry_msgs/msg/Quaternion']  # noqa: N806
    msg = Imu(header=Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
                            frame_id=frame),
              orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
              orientation_covariance=np.zeros(9),
              angular_velocity=Vector3(x=0.1, y=0.2, z=0.3),
              angular_velocity_covariance=np.zeros(9),
              linear_acceleration=Vector3(x=accel[0], y=accel[1], z=accel[2]),
              linear_acceleration_covariance=np.zeros(9))
    return TS.serialize_cdr(msg, 'sensor_msgs/msg/Imu')


def temp_msg(stamp_ns, value):
    """Return a serialized Temperature message."""
    Temperature = TS.types['sensor_msgs/msg/Temperature']  # noqa: N806
    Header = TS.types['std_msgs/msg/Header']  # noqa: N806
    Time = TS.types['builtin_interfaces/msg/Time']  # noqa: N806
    msg = Temperature(header=Header(stamp=Time(sec=stamp_ns // 10**9,
                                               nanosec=stamp_ns % 10**9), frame_id='imu'),
                      temperature=value, variance=0.0)
    return TS.serialize_cdr(msg, 'sensor_msgs/msg/Temperature')


def custom_bag(path, topics, storage=StoragePlugin.MCAP):
    """
    Write a bag from {topic: (msgtype, [(receive_ns, raw), ...])}.

    :return: the bag directory.
    """
    with Writer(path, version=9, storage_plugin=storage) as writer:
        for topic, (msgtype, messages) in topics.items():
            conn = writer.add_connection(topic, msgtype, typestore=TS)
            for receive_ns, raw in messages:
                writer.write(conn, receive_ns, raw)
    return path


def imu_series(n=10, start_ns=10**9, step_ns=10**7, stamped=True):
    """Return Imu messages (receive time, raw); header stamps zero unless stamped."""
    return [(start_ns + i * step_ns,
             imu_msg(start_ns + i * step_ns if stamped else 0, (float(i), 0.0, 9.8)))
            for i in range(n)]


# ---------------------------------------------------------------------------------------
# CSV


@pytest.mark.parametrize('temp,gyro', [(True, True), (False, False), (True, False),
                                       (False, True)])
def test_csv_round_trip(tmp_path, temp, gyro):
    """CSV written by write_samples_csv loads back, with and without temp/gyro."""
    s = make_samples(temp=temp, gyro=gyro)
    path = tmp_path / 'data.csv'
    write_samples_csv(path, s)
    header = path.read_text().splitlines()[0]
    expected = ['t', 'ax', 'ay', 'az'] + (['temp'] if temp else []) + \
        (['gx', 'gy', 'gz'] if gyro else [])
    assert header.split(',') == expected
    assert_same(load_samples(path), s)
    assert load_samples(str(path)).rate_hz == pytest.approx(100.0)


def test_csv_absolute_times_keep_fraction(tmp_path):
    """Absolute (epoch) times survive the CSV with sub-microsecond detail."""
    s = make_samples(n=50, t0=1.7e9)
    path = tmp_path / 'epoch.csv'
    write_samples_csv(path, s)
    np.testing.assert_allclose(load_samples(path).t, s.t, rtol=0, atol=1e-6)


def test_csv_extra_columns_written_and_ignored(tmp_path):
    """Extra columns are written after interface.md ones and ignored on load."""
    s = make_samples(temp=False, gyro=False)
    path = tmp_path / 'extra.csv'
    write_samples_csv(path, s, extra={'window': np.arange(len(s)), 'norm': np.ones(len(s))})
    assert path.read_text().splitlines()[0] == 't,ax,ay,az,window,norm'
    assert_same(load_samples(path), s)


def test_csv_extra_column_errors(tmp_path):
    """Bad extra columns are refused before anything is written."""
    s = make_samples(n=10)
    with pytest.raises(InputError, match='clashes'):
        write_samples_csv(tmp_path / 'x.csv', s, extra={'AX': np.zeros(10)})
    with pytest.raises(InputError, match='values for 10 samples'):
        write_samples_csv(tmp_path / 'x.csv', s, extra={'w': np.zeros(3)})
    with pytest.raises(InputError, match='not usable'):
        write_samples_csv(tmp_path / 'x.csv', s, extra={'a,b': np.zeros(10)})
    assert not os.listdir(tmp_path)


def test_csv_case_insensitive_header_extra_and_order(tmp_path):
    """Header names match case-insensitively, in any order, among extras."""
    path = write_text(tmp_path / 'mixed.csv',
                      'label, AZ ,T,Ay,aX,Temp,note\n'
                      'a,9.8,0.0,0.1,0.2,25,hello\n'
                      'b,9.7,0.5,0.3,0.4,26,world\n')
    s = load_samples(path)
    np.testing.assert_array_equal(s.t, [0.0, 0.5])
    np.testing.assert_array_equal(s.accel, [[0.2, 0.1, 9.8], [0.4, 0.3, 9.7]])
    np.testing.assert_array_equal(s.temp, [25, 26])
    assert s.gyro is None


def test_csv_column_subsets(tmp_path):
    """Optional columns may be present or absent independently."""
    base = 't,ax,ay,az'
    s = load_samples(write_text(tmp_path / 'a.csv', f'{base}\n0,1,2,3\n1,4,5,6\n'))
    assert s.temp is None and s.gyro is None
    s = load_samples(write_text(tmp_path / 'b.csv', f'{base},gx,gy,gz\n0,1,2,3,4,5,6\n'))
    assert s.temp is None
    np.testing.assert_array_equal(s.gyro, [[4, 5, 6]])
    s = load_samples(write_text(tmp_path / 'c.csv', f'{base},temp\n0,1,2,3,30\n'))
    np.testing.assert_array_equal(s.temp, [30])


def test_csv_quotes_bom_blank_lines_and_spaces(tmp_path):
    """Quoted names, a BOM, CRLF, blank lines and padded cells are accepted."""
    path = tmp_path / 'bom.csv'
    path.write_bytes(b'\xef\xbb\xbf"t","ax","ay","az"\r\n0, 1 ,2,3\r\n\r\n1,4,5, 6\r\n')
    s = load_samples(path)
    np.testing.assert_array_equal(s.accel, [[1, 2, 3], [4, 5, 6]])


def test_csv_all_empty_temp_means_no_temperature(tmp_path):
    """An optional column left entirely empty means not recorded."""
    path = write_text(tmp_path / 'a.csv', 't,ax,ay,az,temp,gx,gy,gz\n'
                      '0,1,2,3,,,,\n1,1,2,3,,,,\n')
    s = load_samples(path)
    assert s.temp is None and s.gyro is None
    np.testing.assert_array_equal(s.t, [0, 1])


def test_csv_missing_file_and_kinds(tmp_path):
    """A missing path or an unknown file kind is named in the error."""
    bad(tmp_path / 'nope.csv', 'no such file', 'nope.csv')
    bad(write_text(tmp_path / 'data.txt', 't,ax,ay,az\n0,1,2,3\n'),
        'unsupported', '.csv', '.mcap', '.db3', 'directory')
    bad(write_text(tmp_path / 'noext', 'x'), 'unsupported', '.csv')


@pytest.mark.skipif(hasattr(os, 'geteuid') and os.geteuid() == 0,
                    reason='root reads files without permission')
def test_csv_unreadable(tmp_path):
    """A file without read permission gives a clear error."""
    path = write_text(tmp_path / 'locked.csv', 't,ax,ay,az\n0,1,2,3\n')
    path.chmod(0)
    bad(path, 'cannot read', 'permission')


def test_csv_unreadable_any_user(tmp_path, monkeypatch):
    """Read errors (here simulated, so it also runs as root) become InputError."""
    path = write_text(tmp_path / 'locked.csv', 't,ax,ay,az\n0,1,2,3\n')

    def denied(*args, **kwargs):
        raise PermissionError(13, 'Permission denied')

    monkeypatch.setattr(csv_io, 'open', denied, raising=False)
    bad(path, 'cannot read', 'permission')
    bad(tmp_path, 'metadata.yaml')  # a directory is a bag or nothing
    folder = tmp_path / 'dir.csv'
    folder.mkdir()
    bad(folder, 'not a rosbag2')


def test_csv_empty_header_only_and_binary(tmp_path):
    """Empty, header-only and binary files are refused with the reason."""
    bad(write_text(tmp_path / 'empty.csv', ''), 'empty')
    bad(write_text(tmp_path / 'blank.csv', '\n\n  \n'), 'empty')
    bad(write_text(tmp_path / 'header.csv', 't,ax,ay,az\n'), 'header', 'no data rows')
    path = tmp_path / 'binary.csv'
    path.write_bytes(b'\xff\xfe\x00\x81\x92garbage')
    bad(path, 'not a text')


def test_csv_missing_columns_named(tmp_path):
    """Missing or ambiguous columns are named, with the columns found."""
    msg = bad(write_text(tmp_path / 'a.csv', 'time,ax,ay\n0,1,2\n'),
              'missing required column', 't', 'az', 'found columns')
    assert "'time'" in msg
    bad(write_text(tmp_path / 'b.csv', '0,1,2,3\n1,1,2,3\n'), 'header row', 'numbers')
    bad(write_text(tmp_path / 'c.csv', 't;ax;ay;az\n0;1;2;3\n'), 'comma-separated')
    bad(write_text(tmp_path / 'd.csv', 't,ax,ay,az,gx,gy\n0,1,2,3,4,5\n'),
        'gyro', 'gz')
    bad(write_text(tmp_path / 'e.csv', 't,ax,ay,az,AX\n0,1,2,3,4\n'), "'ax'", 'appears 2')


def test_csv_non_numeric_cell_gives_line(tmp_path):
    """A non-numeric cell is reported with its line and column."""
    path = write_text(tmp_path / 'a.csv', 't,ax,ay,az\n0,1,2,3\n1,1,oops,3\n2,1,2,3\n')
    bad(path, 'line 3', "'ay'", 'oops', 'not a number')


def test_csv_empty_cells(tmp_path):
    """Empty cells and short rows are reported with their lines."""
    bad(write_text(tmp_path / 'a.csv', 't,ax,ay,az\n0,1,2,3\n1,,2,3\n'),
        "'ax'", 'empty', 'line(s) 3')
    bad(write_text(tmp_path / 'b.csv', 't,ax,ay,az,temp\n0,1,2,3,20\n1,1,2,3,\n2,1,2,3,\n'),
        'temperature', 'empty', 'line(s) 3, 4')
    bad(write_text(tmp_path / 'c.csv', 't,ax,ay,az,temp\n0,1,2,3,20\n1,1,2\n'),
        'line 3', 'fields', 'az')


def test_csv_nan_and_inf_rows(tmp_path):
    """Values that are NaN or infinite are reported with the lines holding them."""
    bad(write_text(tmp_path / 'a.csv', 't,ax,ay,az\n0,1,2,3\n1,nan,2,3\n2,1,2,3\n3,1,inf,3\n'),
        'nan or infinite', 'acceleration', '2 row(s)', 'line(s) 3, 5')
    bad(write_text(tmp_path / 'b.csv', 't,ax,ay,az,temp\n0,1,2,3,nan\n'), 'temperature',
        'line(s) 2')
    bad(write_text(tmp_path / 'c.csv', 't,ax,ay,az\n0,1,2,3\n\nnan,1,2,3\n'), 'time',
        'line(s) 4')
    bad(write_text(tmp_path / 'd.csv', 't,ax,ay,az,gx,gy,gz\n0,1,2,3,4,5,-inf\n'), 'gyro')


def test_csv_time_going_backwards(tmp_path):
    """Times out of order are reported with the line."""
    bad(write_text(tmp_path / 'a.csv', 't,ax,ay,az\n0,1,2,3\n2,1,2,3\n1,1,2,3\n'),
        'line 4', 'backwards', 'increasing')


def test_csv_large_file_loads_quickly(tmp_path):
    """A 10^5-row CSV loads in well under the limit."""
    s = make_samples(n=100_000)
    path = tmp_path / 'big.csv'
    write_samples_csv(path, s)
    start = time.perf_counter()
    loaded = load_samples(path)
    assert time.perf_counter() - start < 5.0
    assert_same(loaded, s)


# ---------------------------------------------------------------------------------------
# rosbag2


@pytest.mark.parametrize('suffix', ['.mcap', '.db3'])
@pytest.mark.parametrize('temp,gyro', [(True, True), (False, False)])
def test_bag_file_round_trip(tmp_path, suffix, temp, gyro):
    """A single .mcap/.db3 file round-trips, leaving nothing else behind."""
    s = make_samples(temp=temp, gyro=gyro, t0=1.7e9)
    path = tmp_path / f'session{suffix}'
    assert write_bag(path, s) == path
    assert path.is_file()
    assert sorted(os.listdir(tmp_path)) == [path.name]  # no scratch left behind
    assert_same(load_samples(path), s, rtol=0, atol=0)


@pytest.mark.parametrize('storage,name', [(None, 'session.mcap'), ('sqlite3', 'session.db3')])
def test_bag_directory_round_trip(tmp_path, storage, name):
    """A bag directory round-trips and its storage file loads alone."""
    s = make_samples(n=50)
    bagdir = tmp_path / 'session'
    write_bag(bagdir, s, storage=storage)
    assert sorted(os.listdir(bagdir)) == sorted(['metadata.yaml', name])
    assert_same(load_samples(bagdir), s, rtol=0, atol=0)
    assert_same(load_samples(bagdir / name), s, rtol=0, atol=0)
    with pytest.raises(InputError, match='exists already'):
        write_bag(bagdir, s)


def test_bag_file_replaced_atomically(tmp_path):
    """Writing a bag file over an old one replaces it cleanly."""
    path = tmp_path / 'out.mcap'
    write_bag(path, make_samples(n=20))
    write_bag(path, make_samples(n=30, temp=False))
    s = load_samples(path)
    assert len(s) == 30 and s.temp is None
    assert os.listdir(tmp_path) == ['out.mcap']


def test_bag_custom_topics_and_options(tmp_path):
    """Topic names, storage and time checks of write_bag."""
    s = make_samples(n=20)
    path = write_bag(tmp_path / 'b.mcap', s, imu_topic='sensor/imu',
                     temp_topic='/sensor/temp', frame_id='base')
    assert_same(load_samples(path, imu_topic='/sensor/imu'), s, rtol=0, atol=0)
    assert_same(load_samples(path, imu_topic='sensor/imu', temp_topic='sensor/temp'), s,
                rtol=0, atol=0)
    with pytest.raises(InputError, match='cannot hold'):
        write_bag(tmp_path / 'c.mcap', s, storage='sqlite3')
    with pytest.raises(InputError, match='unknown bag storage'):
        write_bag(tmp_path / 'c.bag', s, storage='rosbag1')
    with pytest.raises(InputError, match='negative'):
        write_bag(tmp_path / 'd.mcap', make_samples(n=5, t0=-1.0))
    with pytest.raises(InputError, match='does not exist'):
        write_bag(tmp_path / 'missing' / 'e.mcap', s)


def test_bag_messages_are_standard(tmp_path):
    """Written messages decode with rosbags itself: fields, stamps, REP-145 markers."""
    s = make_samples(n=5, gyro=False, t0=12.5)
    path = write_bag(tmp_path / 'std.mcap', s, frame_id='imu_frame_odd')
    reader = Reader(path)
    with reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics == {'/imu/data_raw': 'sensor_msgs/msg/Imu',
                          '/imu/temperature': 'sensor_msgs/msg/Temperature'}
        imu = [(c, ts, raw) for c, ts, raw in reader.messages()
               if c.topic == '/imu/data_raw']
    for i, (conn, stamp, raw) in enumerate(imu):
        msg = TS.deserialize_cdr(raw, conn.msgtype)
        assert stamp == round(s.t[i] * 1e9)
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamp
        assert msg.header.frame_id == 'imu_frame_odd'
        a = msg.linear_acceleration
        assert [a.x, a.y, a.z] == s.accel[i].tolist()
        assert msg.orientation.w == 1.0 and msg.orientation_covariance[0] == -1.0
        assert msg.angular_velocity_covariance[0] == -1.0
        assert not msg.linear_acceleration_covariance.any()


def test_bag_mixed_frame_ids_use_the_general_decoder(tmp_path):
    """Messages of differing layout are decoded one by one, with the same result."""
    raws = [imu_msg(10**9 + i, (float(i), 1.0, 2.0), frame='f' * (i % 11)) for i in range(12)]
    slow = rosbag_io._decode_slow(raws, 'sensor_msgs/msg/Imu')
    assert rosbag_io._decode_fast(raws, 'sensor_msgs/msg/Imu') is None
    same = [r for r in raws if len(r) == len(raws[0])]
    fast = rosbag_io._decode_fast(same, 'sensor_msgs/msg/Imu')
    index = [i for i, r in enumerate(raws) if len(r) == len(raws[0])]
    np.testing.assert_array_equal(fast[0], slow[0][index])
    np.testing.assert_array_equal(fast[1], slow[1][index])
    bag = custom_bag(tmp_path / 'mixed', {'/imu': (
        'sensor_msgs/msg/Imu', [(10**9 + i, r) for i, r in enumerate(raws)])})
    s = load_samples(bag)
    np.testing.assert_array_equal(s.accel[:, 0], np.arange(12))
    np.testing.assert_array_equal(s.t, (10**9 + np.arange(12)) * 1e-9)


def test_bag_zero_stamps_fall_back_to_receive_time(tmp_path):
    """Unset header stamps fall back to the receive time."""
    bag = custom_bag(tmp_path / 'raw', {
        '/imu/data_raw': ('sensor_msgs/msg/Imu', imu_series(n=5, stamped=False))})
    s = load_samples(bag)
    np.testing.assert_allclose(s.t, 1.0 + 0.01 * np.arange(5))
    np.testing.assert_array_equal(s.accel[:, 0], np.arange(5))
    np.testing.assert_array_equal(s.gyro, np.tile([0.1, 0.2, 0.3], (5, 1)))
    assert s.temp is None


def test_bag_temperature_interpolated_and_held(tmp_path):
    """Temperature is interpolated onto Imu times and held at the ends."""
    temps = [(int(1.02e9), temp_msg(int(1.02e9), 20.0)),
             (int(1.06e9), temp_msg(int(1.06e9), 24.0))]
    bag = custom_bag(tmp_path / 'tbag', {
        '/imu/data_raw': ('sensor_msgs/msg/Imu', imu_series(n=10)),
        '/imu/temperature': ('sensor_msgs/msg/Temperature', temps)})
    s = load_samples(bag)
    expected = [20, 20, 20, 21, 22, 23, 24, 24, 24, 24]
    np.testing.assert_allclose(s.temp, expected)


def test_bag_topic_selection(tmp_path):
    """Topic choice: several Imu/Temperature topics, named and absent topics."""
    imu = ('sensor_msgs/msg/Imu', imu_series())
    temp = ('sensor_msgs/msg/Temperature', [(10**9, temp_msg(10**9, 30.0))])
    bag = custom_bag(tmp_path / 'two', {'/a/imu': imu, '/b/imu': imu, '/a/temp': temp,
                                        '/b/temp': temp, '/cpu/temp': temp})
    bad(bag, 'several', '/a/imu', '/b/imu', '--imu-topic')
    s = load_samples(bag, imu_topic='/b/imu')  # /b/temp shares the namespace
    np.testing.assert_allclose(s.temp, 30.0)
    bad(bag, '/c/imu', 'not in the bag', '/a/imu', imu_topic='/c/imu')
    bad(bag, '/a/temp', 'not sensor_msgs/Imu', imu_topic='/a/temp')
    bad(bag, 'not in the bag', imu_topic='/a/imu', temp_topic='/nope')

    bag = custom_bag(tmp_path / 'temps', {'/imu': imu, '/t1': temp, '/t2': temp})
    bad(bag, 'several', 'temperature', '/t1', '/t2', '--temp-topic')
    assert load_samples(bag, temp_topic='/t2').temp is not None


def test_bag_without_imu_or_with_empty_topics(tmp_path):
    """No Imu topic, or empty topics, give clear errors."""
    temp = ('sensor_msgs/msg/Temperature', [(10**9, temp_msg(10**9, 30.0))])
    bag = custom_bag(tmp_path / 'noimu', {'/imu/temperature': temp})
    bad(bag, 'no sensor_msgs/Imu topic', '/imu/temperature')

    bag = custom_bag(tmp_path / 'empty', {'/imu': ('sensor_msgs/msg/Imu', [])},
                     storage=StoragePlugin.SQLITE3)
    bad(bag, '/imu', 'no messages')

    bag = custom_bag(tmp_path / 'emptytemp', {
        '/imu': ('sensor_msgs/msg/Imu', imu_series()),
        '/temp': ('sensor_msgs/msg/Temperature', [])})
    assert load_samples(bag).temp is None  # auto-picked and empty: not recorded
    bad(bag, '/temp', 'no messages', temp_topic='/temp')


def test_not_a_bag(tmp_path):
    """Files and folders that are not bags are refused."""
    path = tmp_path / 'junk.mcap'
    path.write_bytes(b'this is not an mcap file at all' * 10)
    bad(path, 'not a readable rosbag2', 'junk.mcap')
    path = tmp_path / 'junk.db3'
    path.write_bytes(b'not sqlite either' * 10)
    bad(path, 'not a readable rosbag2')
    folder = tmp_path / 'folder'
    folder.mkdir()
    bad(folder, 'not a rosbag2 bag directory', 'metadata.yaml')
    write_text(tmp_path / 'folder' / 'data.csv', 't,ax,ay,az\n0,1,2,3\n')
    bad(folder, 'metadata.yaml')


def test_bag_directory_without_metadata_reads_its_file(tmp_path):
    """A bag directory that lost metadata.yaml is read through its file."""
    s = make_samples(n=10)
    bagdir = write_bag(tmp_path / 'lost', s)
    (bagdir / 'metadata.yaml').unlink()
    assert_same(load_samples(bagdir), s, rtol=0, atol=0)


# ---------------------------------------------------------------------------------------
# Atomic writes


def test_atomic_write_text_and_bytes(tmp_path):
    """Atomic writers write the content and leave no temp file."""
    path = tmp_path / 'f.txt'
    atomic_write_text(path, 'hello\n')
    assert path.read_text() == 'hello\n'
    atomic_write_bytes(str(path), b'\x00\x01')
    assert path.read_bytes() == b'\x00\x01'
    assert os.listdir(tmp_path) == ['f.txt']


def test_atomic_write_keeps_permissions(tmp_path):
    """Replacing a file keeps its permission bits."""
    path = tmp_path / 'calib.yaml'
    path.write_text('old')
    path.chmod(0o640)
    atomic_write_text(path, 'new')
    assert path.read_text() == 'new'
    assert path.stat().st_mode & 0o777 == 0o640


def test_atomic_new_file_follows_umask(tmp_path):
    """A new file gets 0o666 minus the umask."""
    old = os.umask(0o027)
    try:
        atomic_write_text(tmp_path / 'n.txt', 'x')
    finally:
        os.umask(old)
    assert (tmp_path / 'n.txt').stat().st_mode & 0o777 == 0o640


def test_atomic_write_failure_keeps_old_file(tmp_path, monkeypatch):
    """A failed rename keeps the old file and leaves no temp file."""
    path = tmp_path / 'data.csv'
    path.write_text('old content')

    def broken_replace(src, dst):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(atomic.os, 'replace', broken_replace)
    with pytest.raises(OSError):
        atomic_write_text(path, 'new content')
    with pytest.raises(InputError, match='cannot write.*No space left'):
        write_samples_csv(path, make_samples(n=5))
    with pytest.raises(InputError, match='cannot write'):
        write_bag(tmp_path / 'data.mcap', make_samples(n=5))
    assert path.read_text() == 'old content'
    assert os.listdir(tmp_path) == ['data.csv']


def test_atomic_write_failure_while_writing(tmp_path):
    """A failure while writing keeps the old file and leaves no temp file."""
    path = tmp_path / 'x.txt'
    path.write_text('old')
    with pytest.raises(AttributeError):
        atomic_write_text(path, None)
    assert path.read_text() == 'old'
    assert os.listdir(tmp_path) == ['x.txt']


def test_atomic_path(tmp_path):
    """The atomic_path context replaces the target on success only and cleans up on failure."""
    path = tmp_path / 'plot.png'
    with atomic_path(path) as tmp:
        assert tmp.endswith('.png') and os.path.dirname(tmp) == str(tmp_path)
        assert not path.exists()
        with open(tmp, 'w') as f:
            f.write('image')
    assert path.read_text() == 'image'
    assert os.listdir(tmp_path) == ['plot.png']

    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            with open(tmp, 'w') as f:
                f.write('half')
            raise RuntimeError('library failed')
    assert path.read_text() == 'image'
    assert os.listdir(tmp_path) == ['plot.png']


def test_atomic_write_through_symlink(tmp_path):
    """Writing through a symbolic link replaces its target, keeps the link."""
    real = tmp_path / 'real.txt'
    real.write_text('old')
    link = tmp_path / 'link.txt'
    link.symlink_to(real)
    atomic_write_text(link, 'new')
    assert link.is_symlink()
    assert real.read_text() == 'new'
