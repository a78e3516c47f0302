"""
A virtual MPU-9250 behind a microcontroller, streaming spec frames on a pseudo-terminal.

Stands in for the hardware in the demo and the tests: open the printed slave path (or
the ``--link`` symlink) as the serial port. The sensor follows a scripted sequence of
held poses (core simulator), the frames carry a ``seq`` counter and a µs device clock
that starts at an arbitrary value and wraps. ``SIGUSR1`` unplugs the device for
``--unplug-s`` seconds and plugs it back in on a new pty (the link is re-pointed);
``SIGINT``/``SIGTERM`` stop it. A summary goes to stderr on exit.

Link faults, as a real board shows them: ``--clock-ppm`` makes the microcontroller's µs
clock run fast (an Uno's ceramic resonator is 0.1-0.3 % off), ``--stall AT:SECONDS`` stops
the UART for a while (the sensor goes on sampling: ``seq`` and ``t_us`` keep counting,
the samples are never sent), ``--unplug-at AT`` unplugs it on a schedule (as SIGUSR1). A
``?`` or ``I`` from the reader is answered with the info frame, as the firmware does.
``--report FILE`` writes what happened as JSON (samples made, frames written whole, and
the samples never sent: unplugged, stalled, pty full).

``--chip`` makes it another chip of ``dataio.wire.chips`` (its WHO_AM_I in the info frame,
its temperature formula on the wire). ``--gyro-errors`` gives the gyroscope a datasheet-sized
scale and misalignment (the rates on the wire still integrate to the scripted turns) and
``--magnetometer`` an AK8963-like
magnetometer in a 48 µT, 60° dip field: its samples (µT, accelerometer frame, NaN
between its 100 Hz samples) are in :attr:`VirtualSensor.last_mag` after each
:meth:`VirtualSensor.counts`; the frames sent are still version 1, without them (frame
v2's magnetometer block is the wire's to add).
"""

import argparse
import math
import os
import signal
import sys
import time

import numpy as np

from .device_port import Pty, Wire
from ..core.constants import G0
from ..dataio.wire import BY_KEY, Converter, DEFAULT_CHIP

CHUNK_S = 10.0
"""Seconds of samples simulated at a time once the script has ended."""
INFO_PERIOD_S = 1.0
"""The info frame is sent at each plug-in and then once a second, as the firmware does."""


def device_effects():
    """
    Return the library effects the virtual device can switch on, in library order.

    Those a random sensor can be given (``Effect.sensor_range``) whose simulation needs no
    history of the session (``Effect.on_device``): the pose held after the script is
    measured sample block by sample block.
    """
    from ..modelgap.effects import EFFECTS
    return tuple(name for name, effect in EFFECTS.items()
                 if effect.sensor_range is not None and effect.on_device)


class DeviceError(Exception):
    """A bad option or input file (exit status 2)."""


def _positive(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}')
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be positive, got {text}')
    return value


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}')
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f'must be in [0, 1), got {text}')
    return value


def _non_negative(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}')
    if not value >= 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def _schedule(text):
    try:
        at, _, seconds = text.partition(':')
        at, seconds = float(at), float(seconds or 'nan')
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected AT:SECONDS, got {text!r}')
    if not (math.isfinite(at) and math.isfinite(seconds) and at >= 0 and seconds > 0):
        raise argparse.ArgumentTypeError(f'expected AT:SECONDS (AT >= 0, SECONDS > 0), got '
                                         f'{text!r}')
    return at, seconds


def _clock_ppm(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}')
    if not math.isfinite(value) or abs(value) > 20000:
        raise argparse.ArgumentTypeError(f'must be within ±20000 ppm, got {text}')
    return value


def add_arguments(parser):
    """
    Add the device options to an argparse parser.

    :param parser: argparse.ArgumentParser (or subparser).
    """
    parser.add_argument('--link', help='maintain a symlink PATH -> current pty slave')
    parser.add_argument('--rate', type=_positive, default=200.0,
                        help='sample rate, Hz (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--poses', default='faces',
                        help='pose script: faces (six faces), random, or a CSV file of '
                             'gravity directions x,y,z in the body frame (default faces)')
    parser.add_argument('--count', type=int, default=None,
                        help='number of random poses (default 12); for faces, repeat the '
                             'six faces up to COUNT poses')
    parser.add_argument('--hold', type=_positive, default=3.0,
                        help='seconds each pose is held (default %(default)s)')
    parser.add_argument('--move', type=_positive, default=1.5,
                        help='seconds each move takes (default %(default)s)')
    parser.add_argument('--loop', action='store_true',
                        help='repeat the script (default: hold the last pose)')
    parser.add_argument('--temp', type=float, default=25.0,
                        help='constant temperature, °C (default %(default)s)')
    parser.add_argument('--temp-ramp', type=float, nargs=2, metavar=('START', 'END'),
                        help='temperature ramp over the script, °C')
    parser.add_argument('--effects', default='',
                        help='comma-separated extra sensor effects: '
                             + ', '.join(device_effects()))
    parser.add_argument('--chip', choices=tuple(BY_KEY), default=DEFAULT_CHIP.key,
                        help='the chip it is (its WHO_AM_I in the info frame, its temperature '
                             'formula; default %(default)s)')
    parser.add_argument('--accel-range', type=int, default=2,
                        choices=sorted(DEFAULT_CHIP.accel_lsb_per_g),
                        help='accelerometer full scale, ±g (default 2)')
    parser.add_argument('--gyro-range', type=int, default=250,
                        choices=sorted(DEFAULT_CHIP.gyro_lsb_per_dps),
                        help='gyroscope full scale, ±°/s (default 250)')
    parser.add_argument('--gravity', type=_positive, default=G0, help='gravity, m/s²')
    parser.add_argument('--noise-from', metavar='ALLAN.json',
                        help='per-sample accel (and gyro) noise from "accel-calib allan '
                             '--json" (white_sample_std, kept at its noise density)')
    parser.add_argument('--truth-out', metavar='FILE.yaml',
                        help='write the true sensor parameters to this YAML file')
    parser.add_argument('--t0-us', type=int, default=None,
                        help='device clock at the first frame, µs (default: random; the '
                             'clock wraps at 2**32)')
    parser.add_argument('--corrupt', type=_fraction, default=0.0,
                        help='fraction of bytes to flip on the wire, e.g. 0.02 (default 0)')
    parser.add_argument('--ascii', action='store_true',
                        help='stream the ASCII line format (t_us,ax,ay,az,temp,gx,gy,gz)')
    parser.add_argument('--frame-version', type=int, choices=(1, 2), default=2,
                        help='binary frame version: 2 (CRC-16, the firmware default) or 1 '
                             '(default %(default)s)')
    parser.add_argument('--unplug-s', type=_non_negative, default=2.0,
                        help='seconds unplugged after SIGUSR1 (default %(default)s)')
    parser.add_argument('--unplug-at', type=_non_negative, action='append', default=[],
                        metavar='AT', help='unplug AT seconds after the start, for --unplug-s '
                        '(repeatable; as SIGUSR1)')
    parser.add_argument('--stall', type=_schedule, action='append', default=[],
                        metavar='AT:SECONDS', help='the UART stops AT s after the start for '
                        'SECONDS: samples made, never sent (repeatable)')
    parser.add_argument('--clock-ppm', type=_clock_ppm, default=0.0,
                        help='the device µs clock runs this many ppm fast (negative: slow; '
                             'default 0)')
    parser.add_argument('--report', metavar='FILE.json',
                        help='at exit, write what was made, sent and never sent as JSON')
    parser.add_argument('--duration', type=_positive, default=None,
                        help='stop after this many seconds (default: run until SIGINT)')
    parser.add_argument('--gyro-errors', action='store_true',
                        help='gyroscope scale ±3 %% and cross-axis ±2 %% (datasheet)')
    parser.add_argument('--magnetometer', action='store_true',
                        help='simulate an AK8963-like magnetometer too (its samples are not '
                             'sent in version-1 frames)')
    return parser


def _directions(args, rng):
    from .motion import face_directions, random_directions
    if args.poses == 'faces':
        faces = face_directions()
        count = args.count or 6
        return faces[np.arange(count) % 6]
    if args.poses == 'random':
        return random_directions(args.count or 12, rng)
    path = args.poses
    from ..core.errors import InputError
    from ..dataio.atomic import regular_opener
    try:
        with open(path, encoding='utf-8', opener=regular_opener) as f:   # never a FIFO
            rows = []
            for number, line in enumerate(f, 1):
                text = line.strip()
                if not text or text.startswith('#'):
                    continue
                fields = text.replace(';', ',').split(',')
                try:
                    rows.append([float(v) for v in fields[:3]])
                except ValueError:
                    if rows or number > 1:
                        raise DeviceError(f'{path}:{number}: expected x,y,z numbers')
                    continue                     # header row
                if len(fields) < 3:
                    raise DeviceError(f'{path}:{number}: expected x,y,z numbers')
    except OSError as err:
        raise DeviceError(f'cannot read pose file {path}: {err.strerror}')
    except InputError as err:
        raise DeviceError(f'pose file {err}') from None
    except UnicodeDecodeError:
        raise DeviceError(f'pose file {path} is not UTF-8 text') from None
    d = np.asarray(rows, float).reshape(-1, 3)
    if len(d) == 0:
        raise DeviceError(f'pose file {path} holds no poses')
    with np.errstate(over='ignore', invalid='ignore'):
        norms = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(norms)) or np.any(norms < 1e-9):
        raise DeviceError(f'pose file {path}: every direction needs a non-zero finite length')
    d = d / norms[:, None]
    return d[np.arange(args.count) % len(d)] if args.count else d


class VirtualSensor:
    """
    Sample source: the scripted session, then the last pose held (or the script looped).

    :param args: parsed options.
    """

    def __init__(self, args):
        from .sensor import mpu9250_like
        self.rng = np.random.default_rng(args.seed)
        effects = [e for e in args.effects.split(',') if e]
        known = device_effects()
        for name in effects:
            if name not in known:
                raise DeviceError(f'unknown effect {name!r}: use {", ".join(known)}')
        self.sensor = mpu9250_like(self.rng, rate_hz=args.rate, effects=effects)
        if getattr(args, 'noise_from', None):
            from ..core.errors import InputError
            from ..dataio.noise_file import noise_from_allan
            try:
                self.sensor.noise_std, gyro = noise_from_allan(args.noise_from, args.rate)
            except InputError as err:
                raise DeviceError(str(err)) from None
            if gyro is not None:
                self.sensor.gyro_noise_std = gyro
        self._imu_parts(args)
        self.args = args
        self.directions = _directions(args, self.rng)
        self.chip = BY_KEY[getattr(args, 'chip', DEFAULT_CHIP.key)]
        try:
            self.converter = Converter(args.accel_range, args.gyro_range, chip=self.chip)
        except ValueError as err:
            raise DeviceError(f'{self.chip.name}: {err}') from None
        self.t_offset = 0.0
        self._stream = None
        self._played = False
        self._queue = []
        self.last_mag = None        # magnetometer samples of the last counts(), µT
        self._field = None          # field in the body frame at the last sample, µT

    def _imu_parts(self, args):
        """Gyroscope errors and magnetometer from generators of their own."""
        from .sensor import ak8963_like, with_gyro_errors
        if getattr(args, 'gyro_errors', False):
            self.sensor = with_gyro_errors(self.sensor,
                                           np.random.default_rng([args.seed, 19, 1]))
        if getattr(args, 'magnetometer', False):
            chip = BY_KEY[getattr(args, 'chip', DEFAULT_CHIP.key)]
            if chip.magnetometer is None:
                raise DeviceError(f'--magnetometer: the {chip.name} has no magnetometer')
            self.sensor.magnetometer = ak8963_like(np.random.default_rng([args.seed, 19, 2]))
        self._mag_rng = np.random.default_rng([args.seed, 19, 3])

    def truth(self):
        """Return the true parameters as a YAML-ready mapping (m/s², °C, s)."""
        s = self.sensor
        a = self.args
        return {'T': s.T.tolist(), 'bias_m_s2': s.bias.tolist(),
                'noise_std_m_s2': s.noise_std.tolist(), 'lsb_m_s2': float(s.lsb),
                'nonlinearity': s.nonlinearity.tolist(),
                'bias_tempco_m_s2_per_c': s.bias_tempco.tolist(),
                'scale_tempco_per_c': s.scale_tempco.tolist(),
                'bias_drift_m_s2_per_s': s.bias_drift.tolist(),
                'temp_ref_c': float(s.temp_ref), 'gravity_m_s2': float(a.gravity),
                'rate_hz': float(a.rate), 'accel_range_g': a.accel_range,
                'gyro_range_dps': a.gyro_range, 'directions': self.directions.tolist(),
                'hold_s': float(a.hold), 'move_s': float(a.move),
                'temperature_c': list(a.temp_ramp) if a.temp_ramp else float(a.temp),
                'gyro_bias_rad_s': s.gyro_bias.tolist(), 'gyro_T': s.gyro_T.tolist(),
                **self._magnetometer_truth()}

    def _magnetometer_truth(self):
        """Return the magnetometer's true parameters and the field, or {} without one."""
        mag = self.sensor.magnetometer
        if mag is None:
            return {}
        from .sensor import EarthField
        field = EarthField()
        return {'magnetometer': {'T': mag.T.tolist(), 'hard_iron_uT': mag.hard_iron.tolist(),
                                 'R': mag.R.tolist(), 'noise_std_uT': mag.noise_std.tolist(),
                                 'rate_hz': float(mag.rate_hz)},
                'earth_field': {'field_uT': field.field_uT, 'dip_deg': field.dip_deg}}

    def _script(self):
        """Return the scripted session as a generator of (n, 7) count blocks."""
        from .motion import iter_session
        a = self.args
        temperature = tuple(a.temp_ramp) if a.temp_ramp else a.temp
        # In pieces of CHUNK_S: a long --hold never builds the whole session in memory
        # and a stop request is seen between pieces.
        for piece in iter_session(self.sensor, self.directions, self.rng, hold_s=a.hold,
                                  move_s=a.move, rate_hz=a.rate, gravity=a.gravity,
                                  temperature=temperature,
                                  chunk_rows=max(int(CHUNK_S * a.rate), 1)):
            s = piece.samples
            if piece.true_field is not None:
                self._field = piece.true_field[-1]
            yield self.converter.to_counts_array(s.accel, s.temp, s.gyro), s.mag

    def _next_block(self, t_next):
        """Return the next block of counts: the script, then the last pose held (or again)."""
        while True:
            if self._stream is None and (not self._played or self.args.loop):
                self._stream = self._script()
                self._played = True
            if self._stream is None:
                return self._hold(t_next)
            block = next(self._stream, None)
            if block is not None:
                return block
            self._stream = None

    def _hold(self, t_start):
        a = self.args
        n = int(round(CHUNK_S * a.rate))
        t = t_start + np.arange(n) / a.rate
        temp = np.full(n, a.temp_ramp[1] if a.temp_ramp else a.temp)
        true = np.tile(a.gravity * self.directions[-1], (n, 1))
        accel = self.sensor.measure(true, self.rng, temp, t)
        # Held still: the true rate is zero, the raw rate its bias and noise (as in the
        # script: raw = gyro_T · true + bias + noise), so a held pose after the script
        # reads like any held pose of it.
        gyro = self.sensor.gyro_bias + self.rng.standard_normal((n, 3)) \
            * self.sensor.gyro_noise_std
        return self.converter.to_counts_array(accel, temp, gyro), self._held_mag(t)

    def _held_mag(self, t):
        """Magnetometer samples (n, 3) µT of the last pose held (NaN between its samples)."""
        mag = self.sensor.magnetometer
        if mag is None or self._field is None:
            return None
        from .sensor import measure_mag
        return measure_mag(mag, np.tile(self._field, (len(t), 1)), t, 1.0 / self.args.rate,
                           self._mag_rng)

    def counts(self, n, t_next):
        """
        Return the next ``n`` samples as an (n, 7) int16 array.

        :param t_next: session time of the first of them, s.
        """
        parts, mags, have = [], [], 0
        while have < n:
            if not self._queue:
                self._queue.append(self._next_block(t_next + have / self.args.rate))
            block, mag = self._queue[0]
            take = min(n - have, len(block))
            parts.append(block[:take])
            mags.append(np.full((take, 3), np.nan) if mag is None else mag[:take])
            if take == len(block):
                self._queue.pop(0)
            else:
                self._queue[0] = (block[take:], None if mag is None else mag[take:])
            have += take
        self.last_mag = None if self.sensor.magnetometer is None else (
            np.concatenate(mags) if mags else np.zeros((0, 3)))
        return np.concatenate(parts) if parts else np.zeros((0, 7), np.int16)


class _Flags:
    stop = False
    unplug = False


def run(args):
    """
    Run the virtual device until SIGINT/SIGTERM (or ``--duration``).

    :param args: argparse namespace with the options of :func:`add_arguments`.
    :return: exit status (0, or 2 on bad input with a one-line reason on stderr).
    """
    try:
        if args.count is not None and args.count < 1:
            raise DeviceError(f'--count must be >= 1, got {args.count}')
        sensor = VirtualSensor(args)
        if args.link and os.path.isdir(args.link):
            raise DeviceError(f'--link {args.link} is a directory')
        if args.link and os.path.lexists(args.link) and not os.path.islink(args.link):
            raise DeviceError(f'--link {args.link} exists and is not a symlink: replacing it '
                              'would destroy it (choose a new name)')
        if args.link and not os.path.isdir(os.path.dirname(os.path.abspath(args.link))):
            raise DeviceError(f'--link {args.link}: the folder does not exist')
        if args.truth_out:
            _write_truth(args.truth_out, sensor.truth())
    except DeviceError as err:
        from ..dataio.formats import message_line
        print(message_line(f'simulate-device: {err}'), file=sys.stderr)
        return 2

    flags = _Flags()

    def on_stop(signum, frame):
        flags.stop = True

    def on_unplug(signum, frame):
        flags.unplug = True

    old = {sig: signal.signal(sig, handler) for sig, handler in
           ((signal.SIGINT, on_stop), (signal.SIGTERM, on_stop), (signal.SIGUSR1, on_unplug))}
    wire = Wire(args, sensor.rng)
    unplugs = 0
    never = {'unplugged': 0, 'stalled': 0, 'buffer_full': 0}   # samples made, never sent
    written = 0                                  # frames (or lines) written whole
    stalls = [(at, at + seconds) for at, seconds in getattr(args, 'stall', [])]
    unplug_at = sorted(getattr(args, 'unplug_at', []))
    pty = None
    start_time = time.time()
    sent = 0                                     # samples made (sent or not)
    try:
        pty = Pty(args.link)
        print(pty.path, flush=True)
        has_mag = sensor.sensor.magnetometer is not None
        pty.write(wire.info(has_mag))
        info_due = time.monotonic() + INFO_PERIOD_S
        start = time.monotonic()
        start_time = time.time()
        batch_s = min(0.01, 2.0 / args.rate)
        while not flags.stop:
            now = time.monotonic()
            if args.duration is not None and now - start >= args.duration:
                break
            if unplug_at and now - start >= unplug_at[0]:
                unplug_at.pop(0)
                flags.unplug = True
            if flags.unplug:
                flags.unplug = False
                unplugs += 1
                pty.close()
                pty = None
                print(f'simulate-device: unplugged for {args.unplug_s:g} s', file=sys.stderr,
                      flush=True)
                until = time.monotonic() + args.unplug_s
                while not flags.stop and time.monotonic() < until:
                    time.sleep(0.01)
                if flags.stop:
                    break
                now = time.monotonic()
                missed = int((now - start) * args.rate) + 1 - sent
                if missed > 0:                   # the sensor went on while unplugged
                    sensor.counts(missed, sent / args.rate)
                    wire.skip(missed)
                    never['unplugged'] += missed
                    sent += missed
                pty = Pty(args.link)
                print(pty.path, flush=True)
                pty.write(wire.info(has_mag))
            stalled = any(a <= now - start < b for a, b in stalls)
            if pty is not None and not stalled:
                asked = pty.requests()
                if b'?' in asked or b'I' in asked or now >= info_due:
                    pty.write(wire.info(has_mag))            # on request, and once a second
                    info_due = now + INFO_PERIOD_S
            due = int((now - start) * args.rate) + 1
            if due > sent:
                n = due - sent
                counts = sensor.counts(n, sent / args.rate)
                if pty is None or stalled:
                    wire.skip(n)
                    never['unplugged' if pty is None else 'stalled'] += n
                else:
                    data = wire.encode(counts, sent, wire.mag_blocks(sensor.last_mag))
                    whole = wire.whole_frames(len(data) - pty.write(data))
                    written += whole
                    never['buffer_full'] += n - whole
                sent = due
            next_due = start + sent / args.rate
            time.sleep(max(batch_s, next_due - time.monotonic()))
    finally:
        if pty is not None:
            pty.close()
        for sig, handler in old.items():
            signal.signal(sig, handler)
    kind = 'lines' if args.ascii else 'frames'
    dropped = sum(never.values())
    print(f'simulate-device: {wire.frames} {kind} written, {wire.bytes_corrupted} bytes '
          f'corrupted in {wire.frames_damaged} {kind}, {dropped} {kind} never sent '
          f'(unplugged {never["unplugged"]}, stalled {never["stalled"]}, pty full '
          f'{never["buffer_full"]}), {unplugs} unplug(s)', file=sys.stderr, flush=True)
    if getattr(args, 'report', None):
        _write_report(args.report, {
            'samples': sent, 'frames_written': written, 'never_sent': never,
            'unplugs': unplugs, 'stalls': len(stalls), 'rate_hz': args.rate,
            'clock_ppm': wire.clock_ppm, 't0_us': wire.t0_us, 'frame_version': wire.version,
            'start_time': start_time, 'bytes_corrupted': wire.bytes_corrupted})
    return 0


def _write_report(path, report):
    import json
    from ..dataio.atomic import atomic_write_text
    try:
        atomic_write_text(path, json.dumps(report, indent=1) + '\n')
    except Exception as err:            # noqa: B902 - the report must not hide the run
        print(f'simulate-device: cannot write {path}: {err}', file=sys.stderr)


def _write_truth(path, truth):
    import yaml
    from ..core.errors import InputError
    from ..dataio.atomic import atomic_write_text
    try:
        atomic_write_text(path, yaml.safe_dump(truth, sort_keys=False))
    except InputError as err:
        raise DeviceError(str(err)) from None
    except OSError as err:
        raise DeviceError(f'cannot write {path}: {err.strerror or err}') from None


def main(argv=None):
    """Command-line entry point (``python -m accel_calib_ros.sim.device``)."""
    parser = argparse.ArgumentParser(prog='python -m accel_calib_ros.sim.device',
                                     description=__doc__.strip().splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
