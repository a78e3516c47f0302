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


# -- every lost sample counted, no valid byte thrown away -----------------------------------------


def delivered(got):
    return [index(f) for f in got['frames']]


def test_a_uart_stall_is_counted_and_nothing_is_flushed():
    """2.5 s not sent (seq and t_us go on); the watchdog reopens meanwhile: all counted."""
    clock = FakeClock()
    device = FakeDevice(clock, ppm=2000)
    device.stalls.append((clock.t + 3.0, clock.t + 5.5))
    link, _, got, log = make_link(device, clock)
    run_link(link, 9.0)
    sent = [k for k, _ in device.sent]
    assert delivered(got) == sent[:len(got['frames'])] and len(got['frames']) >= len(sent) - 5
    assert link.watchdog_reopens >= 1 and device.flushed == 0
    snap = link.snapshot()
    assert snap['counters']['lost_frames'] == device.never_sent == 1250
    assert snap['counters']['gaps_uncounted'] == 0 and snap['clock_resets'] == 0
    stamps = got['stamps']
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_a_replug_keeps_what_the_device_sent_before_the_reopen():
    """Unplugged 2 s; the back-off reopens up to 1.6 s after the replug: those bytes stay."""
    clock = FakeClock()
    device = FakeDevice(clock)
    device.unplugs.append((clock.t + 3.0, clock.t + 5.0))
    link, _, got, log = make_link(device, clock, reconnect_max_s=1.6)
    run_link(link, 10.0)
    assert device.opens == 2 and link.reconnects == 1
    back = [k for k, t in device.sent if clock.t - 5.0 < t < clock.t - 0.05]
    assert set(back) <= set(delivered(got))             # nothing sent after the replug lost
    snap = link.snapshot()
    assert snap['counters']['lost_frames'] == device.never_sent + device.vanished
    assert device.never_sent == 1000 and snap['counters']['gaps_uncounted'] == 0
    assert log.count('lost /dev/fake') == 1 and log.count('reconnected') == 1


def test_a_device_restart_is_not_counted_and_restarts_the_mapping():
    clock = FakeClock()
    device = FakeDevice(clock)
    device.restarts.append(clock.t + 3.0)
    link, _, got, log = make_link(device, clock)
    run_link(link, 6.0)
    snap = link.snapshot()
    assert snap['counters']['lost_frames'] == 0 and snap['counters']['gaps_uncounted'] == 1
    assert snap['clock_resets'] == 1 and device.never_sent == 0
    assert delivered(got)[-1] >= 0.95 * 6.0 * device.rate
    stamps = got['stamps']
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_frames_wait_for_the_info_frame_of_their_connection():
    """The info frame is asked for at once; frames never go out before it (ranges)."""
    clock = FakeClock()
    device = FakeDevice(clock)
    device.info = device.info._replace(accel_range_g=8)
    device.stalls.append((clock.t + 3.0, clock.t + 4.0))     # silent: the watchdog reopens
    events = []
    link, _, got, log = make_link(device, clock, timestamp='host')
    link.on_info = lambda info: events.append(('info', info.accel_range_g))
    link.on_connect = lambda: events.append(('connect', None))
    link.on_samples = lambda frames, stamps: events.append(('frames', len(frames)))
    run_link(link, 6.0)
    assert link.watchdog_reopens >= 1 and device.requests >= 2
    connects = [k for k, e in enumerate(events) if e[0] == 'connect']
    assert len(connects) >= 2
    for k in connects:                                  # after each (re)open: info first
        later = [e for e in events[k + 1:] if e[0] != 'connect']
        assert later and later[0] == ('info', 8), events[k:k + 3]
    assert link.snapshot()['info'].accel_range_g == 8


def test_a_source_without_info_frames_is_waited_for_once():
    clock = FakeClock()
    device = FakeDevice(clock, info=None)
    device.stalls.append((clock.t + 4.0, clock.t + 5.0))
    link, _, got, log = make_link(device, clock, timestamp='host')
    first = []
    link.on_samples = lambda frames, stamps: first.append((clock.t, len(frames)))
    run_link(link, 8.0)
    assert first[0][0] - 1000.0 == pytest.approx(1.5, abs=0.05)     # HOLD_MAX_S, once
    assert log.count('no info frame') == 1 and link.info_timeouts == 1
    assert link.watchdog_reopens >= 1                   # a reopen does not wait again
    gaps = [b[0] - a[0] for a, b in zip(first, first[1:])]
    assert max(gaps) < 1.5


def test_a_stale_not_streaming_status_is_cleared_when_the_link_goes_silent():
    """Regression: an old 'not streaming' info frame disabled the watchdog for good."""
    clock = FakeClock()
    device = FakeDevice(clock, streaming=False)
    device.info = device.info._replace(status=2, who_am_i=0)
    device.stalls.append((clock.t + 3.0, clock.t + 100.0))  # the board hangs
    link, _, got, log = make_link(device, clock)
    run_link(link, 2.5)
    prev = link.snapshot()
    run_link(link, 0.5)
    level, message = assess(link.snapshot(), prev, 0.5)
    assert level == ERROR and message.startswith('firmware: no sensor answers')
    assert link.watchdog_reopens == 0
    run_link(link, 6.0)
    prev = link.snapshot()
    run_link(link, 1.0)
    level, message = assess(link.snapshot(), prev, 0.5)
    assert level == ERROR and message.startswith('no valid frame for')
    assert link.watchdog_reopens >= 1


def test_the_snapshot_is_taken_under_the_readers_lock():
    """Regression: the diagnostics read parser.period_us twice while the reader reset it."""
    import threading
    link, device, got, log = make_link()
    run_link(link, 2.0)
    taken = []
    with link._lock:
        thread = threading.Thread(target=lambda: taken.append(link.snapshot()))
        thread.start()
        thread.join(0.2)
        assert not taken                                # it waits for the reader's step
    thread.join(2.0)
    assert taken and taken[0]['period_us'] == pytest.approx(2000.0)
    snap = dict(taken[0], period_us=None)               # reset in between: no TypeError
    assert 'device_rate_hz' not in link_values(snap, snap)


def test_only_the_first_open_and_a_new_port_or_rate_flush_the_input():
    """What waited before the driver started is not this session's; a reopen keeps all."""
    clock = FakeClock()
    device = FakeDevice(clock)
    clock.t += 0.5                                      # the device streamed before we came
    link, _, got, log = make_link(device, clock)
    run_link(link, 2.0)
    assert device.flushed >= 250 * 25                  # 0.5 s of frames (and an info frame)
    assert delivered(got)[0] >= 250
    flushed = device.flushed
    link.reopen(port='/dev/fake')                       # same port, same rate: kept
    run_link(link, 1.0)
    assert device.flushed == flushed and device.opens == 2
    link.reopen(baud=500_000)
    run_link(link, 0.01)
    assert device.opens == 3 and link.baud == 500_000
    link.reopen(port='/dev/other')
    run_link(link, 0.01)
    assert device.opens == 4 and link.port == '/dev/other'


def test_open_serial_keeps_what_the_os_buffered():
    """Keep the input at opening: pyserial's own open() flushes it (tcflush)."""
    import os
    import tty
    from accel_calib_ros.dataio.link import open_serial
    import serial
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    try:
        os.write(master, b'kept bytes')
        plain = serial.Serial(path, 115200, timeout=0.2)
        assert plain.read(10) == b''                    # what pyserial alone does
        plain.close()
        os.write(master, b'kept bytes')
        port = open_serial(path, 115200, 0.2)
        assert port.read(10) == b'kept bytes'
        os.write(master, b'dropped')
        port.reset_input_buffer()                       # on request, it still flushes
        assert port.read(7) == b''
        port.close()
    finally:
        os.close(master)
        os.close(slave)
