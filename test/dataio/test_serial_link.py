"""
The serial link without ROS and without hardware: a fake device on a fake port, fake time.

The link is stepped by hand (``link.step()``); time moves only when it waits or reads, so
back-off delays, the watchdog and the info requests are checked to the millisecond.
"""

from accel_calib_ros.dataio.link import assess, ERROR, link_values, OK, SerialLink, WARN
from link_fakes import FakeClock, FakeDevice, run_link
import pytest


class Log:
    """A logger that keeps its lines."""

    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    def warning(self, text):
        self.lines.append(('warning', text))

    def error(self, text):
        self.lines.append(('error', text))

    def count(self, word):
        return sum(word in text for _, text in self.lines)


def make_link(device=None, clock=None, **options):
    clock = clock or FakeClock()
    device = device or FakeDevice(clock)
    got = {'frames': [], 'stamps': [], 'infos': []}
    log = Log()

    def on_samples(frames, stamps):
        got['frames'] += frames
        got['stamps'] += stamps
    options.setdefault('reconnect_min_s', 0.2)
    link = SerialLink('/dev/fake', 1_000_000, open_port=device.opener, clock=clock,
                      logger=log, on_samples=on_samples, on_info=got['infos'].append,
                      **options)
    return link, device, got, log


def index(frame):
    return frame.counts[0]


def test_stream_is_delivered_in_order_with_increasing_stamps():
    link, device, got, log = make_link()
    run_link(link, 3.0)
    frames = got['frames']
    assert len(frames) >= 0.95 * 3.0 * device.rate
    assert [index(f) for f in frames] == list(range(index(frames[0]), index(frames[-1]) + 1))
    stamps = got['stamps']
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert got['infos'] and got['infos'][0].chip == 'MPU-9250'
    snap = link.snapshot()
    assert snap['connected'] and snap['counters']['lost_frames'] == 0
    assert snap['version'] == 2 and snap['period_us'] == pytest.approx(2000.0)
    assert log.count('connected to /dev/fake') == 1


def test_a_missing_port_is_retried_with_back_off_and_logged_once():
    clock = FakeClock()
    device = FakeDevice(clock)
    device.unplugs.append((clock.t, clock.t + 10.0))
    attempts = []
    opener = device.opener

    def counting_opener(*args):
        attempts.append(clock.t)
        return opener(*args)
    link, _, got, log = make_link(device, clock, reconnect_max_s=2.0)
    link.open_port = counting_opener
    run_link(link, 14.0)
    gaps = [round(b - a, 3) for a, b in zip(attempts, attempts[1:])]
    assert gaps[:5] == [0.2, 0.4, 0.8, 1.6, 2.0]
    assert got['frames'] and link.connected
    assert log.count('cannot open') == 1
    assert link.snapshot()['reconnects'] == 0       # never connected before: not a re-


def test_the_reader_survives_an_exception_and_counts_it():
    link, device, got, log = make_link()
    real_feed = link.parser.feed
    calls = []

    def failing_feed(data, *args):
        calls.append(len(data))
        if len(calls) == 3:
            raise AttributeError("'tuple' object has no attribute 'seq'")
        return real_feed(data, *args)
    link.parser.feed = failing_feed
    run_link(link, 2.0)
    assert link.reader_errors == 1 and 'AttributeError' in link.last_reader_error
    assert log.count('serial reader failed') == 1
    assert got['frames'][-1].counts[0] >= 0.9 * 2.0 * device.rate


def test_a_silent_port_is_reopened_by_the_watchdog():
    clock = FakeClock()
    device = FakeDevice(clock)
    device.stalls.append((clock.t + 3.0, clock.t + 6.0))
    link, _, got, log = make_link(device, clock)
    run_link(link, 3.2)
    prev = link.snapshot()
    run_link(link, 1.0)
    level, message = assess(link.snapshot(), prev, 0.5)
    assert level == ERROR and 'no valid frame' in message
    run_link(link, 5.0)
    assert link.watchdog_reopens >= 2
    prev = link.snapshot()
    run_link(link, 1.0)
    assert assess(link.snapshot(), prev, 0.5)[0] in (OK, WARN)


def test_the_info_frame_is_asked_for_when_none_came():
    clock = FakeClock()
    device = FakeDevice(clock, info=None)
    link, _, got, log = make_link(device, clock)
    run_link(link, 10.0)
    assert device.requests == 3 and got['infos'] == []
    assert got['frames']


def snapshot(**changes):
    counters = {'frames': 0, 'crc_errors': 0, 'lost_frames': 0, 'rejected': 0,
                'bytes_skipped': 0, 'frames_v1': 0, 'frames_v2': 0, 'timing_jitter': 0,
                'internal_errors': 0}
    counters.update(changes.pop('counters', {}))
    snap = {'time': 10.0, 'counters': counters, 'connected': True, 'last_error': '',
            'reconnects': 0, 'reader_errors': 0, 'last_reader_error': '',
            'watchdog_reopens': 0, 'last_frame_at': 9.99, 'first_open_at': 1.0,
            'opened_at': 1.0, 'binary': True, 'format': 'binary', 'timestamp': 'device',
            'baud': 1_000_000, 'port': '/dev/x', 'info': None, 'version': 2,
            'quality': 1.0, 'strict': False, 'jitter_us': 3.0, 'period_us': 1000.0,
            'drift_ppm': 0.0}
    snap.update(changes)
    return snap


def test_assess_levels_from_snapshots():
    prev = snapshot(time=9.0)
    assert assess(snapshot(counters={'frames': 1000}), prev, 0.5) == (OK, 'streaming')
    level, message = assess(snapshot(counters={'frames': 990, 'lost_frames': 10}), prev, 0.5)
    assert level == WARN and '10 lost frames' in message and '1.0 %' in message
    level, message = assess(snapshot(connected=False, last_error='gone'), prev, 0.5)
    assert (level, message) == (ERROR, 'not connected: gone')
    level, message = assess(snapshot(last_frame_at=8.0, counters={'frames': 5}), prev, 0.5)
    assert level == ERROR and 'no valid frame for 2.0 s' in message
    level, _ = assess(snapshot(reader_errors=1, counters={'frames': 1000}), prev, 0.5)
    assert level == ERROR
    values = link_values(snapshot(counters={'frames': 1000}), prev)
    assert values['frame_rate_hz'] == '1000.0' and values['device_rate_hz'] == '1000.0'


def test_assess_names_why_and_counts_failed_publishes():
    prev = snapshot(time=9.0)
    assert assess(snapshot(connected=False), prev, 0.5) == \
        (ERROR, 'not connected: the port is not open yet')
    assert assess(snapshot(connected=False, stopped=True), prev, 0.5) == \
        (ERROR, 'not connected: the reader has stopped')
    some = snapshot(counters={'frames': 1000}, published=990, publish_errors=10,
                    last_publish_error='imu/data_raw: RuntimeError: cannot publish data')
    level, message = assess(some, dict(prev, published=0, publish_errors=0), 0.5)
    assert level == WARN and message.startswith('10 messages could not be published')
    assert 'cannot publish data' in message and 'goes on' in message
    none = dict(some, published=0, publish_errors=1000)
    assert assess(none, dict(prev, published=0, publish_errors=0), 0.5)[0] == ERROR
