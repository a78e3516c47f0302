"""
``accel-calib guide``: a calibration walked through live in the terminal.

It reads a serial port (§1 frames, through ``dataio.link`` as the driver does), a ROS
topic or a simulated sensor held by a simulated person, and shows where gravity points
now against the pose asked for, how long to keep holding, the windows collected and the
predicted accuracy against the target; it draws the board in the next pose, says
"enough", and ends the session as ``fit`` and the node do (``session.finish``: the same
acceptance, the file written atomically, the history).

Only the standard library and numpy (and the session floor's settings) are imported here
at module level; rich, the serial link and rclpy are imported when the guide needs them.

When the source gives the angular rate (serial frames, an Imu topic with it, the
simulation) the screen says which rotation axis the moves have not turned about yet, and
with a magnetometer (version-2 frames, ``--mag-topic``, the simulation) how much of the
sphere of field directions it has seen and where to turn; at the end the gyroscope's
scale and misalignment and the magnetometer are fitted and stored beside the
accelerometer when they pass their limits (as ``fit``), else reported.
"""

import math
import os
import sys
import time

import numpy as np

from .common import (check_output, GRAVITY, non_negative, positive, positive_upto, ranged,
                     same_file, SEED, sensor_id, TEMPERATURE, UsageError)
from .guide_session import GuideSession
from .guide_sources import RosSource, SerialSource, SimulatedSource
from ..core.advice import DEFAULT_TARGET, MIN_WINDOWS, pose_name
from ..core.errors import InputError
from ..session.settings import DEFAULT_SETTINGS, GUIDED_METHODS


def add_arguments(p):
    """Add the options of ``guide`` to its parser."""
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument('--port', help='serial port of the MPU9250 board (interface §1 frames)')
    src.add_argument('--topic', help='sensor_msgs/Imu topic to listen to (ROS 2)')
    src.add_argument('--simulate', action='store_true',
                     help='a simulated sensor held by a simulated person who follows the '
                          'advice')
    p.add_argument('-o', '--output', help="calibration YAML to write (default: the nodes' "
                                          'file of --sensor, $ROS_HOME/accel_calib_ros/'
                                          '<sensor>/calibration.yaml)')
    p.add_argument('--method', choices=GUIDED_METHODS, default=DEFAULT_SETTINGS.method)
    p.add_argument('--target', type=positive, default=DEFAULT_TARGET,
                   help='predicted accuracy that is enough, m/s² (default %(default)s)')
    p.add_argument('--gravity', type=GRAVITY, default=DEFAULT_SETTINGS.gravity)
    p.add_argument('--max-predicted-error', type=ranged(1e-9, 1e3),
                   default=DEFAULT_SETTINGS.max_predicted_error, metavar='M_S2',
                   help='refuse to write a calibration whose predicted accuracy is worse '
                        'than this, m/s² (default %(default)s, as fit and the node)')
    p.add_argument('--hold', type=positive, default=2.0,
                   help='seconds to hold each pose still (default %(default)s)')
    p.add_argument('--record', help='also write the raw samples to this CSV')
    p.add_argument('--history', nargs='?', const='', default=None, metavar='DB',
                   help='keep the windows and the calibration in this per-sensor history '
                        '(default next to the calibration file)')
    p.add_argument('--sensor', type=sensor_id,
                   help='sensor id, as the nodes name it (namespace/frame_id: robot1/imu_link; '
                        'default imu_link, their default): recorded in the calibration and '
                        'the history, and it picks their default files')
    p.add_argument('--timeout', type=positive, default=None,
                   help='give up after this many wall-clock seconds')
    from ..dataio.wire.chips import DEFAULT_CHIP
    g = p.add_argument_group('serial port (read as the driver reads it: the chip and its '
                             "ranges from the firmware's info frame)")
    g.add_argument('--baud', type=int, default=1000000)
    g.add_argument('--ascii', action='store_true', help='ASCII line format instead of frames')
    g.add_argument('--accel-range', type=int, default=2,
                   choices=tuple(DEFAULT_CHIP.accel_lsb_per_g),
                   help='accelerometer full scale, ±g, without an info frame (default 2)')
    g.add_argument('--gyro-range', type=int, default=250,
                   choices=tuple(DEFAULT_CHIP.gyro_lsb_per_dps),
                   help='gyroscope full scale, ±°/s, without an info frame (default 250)')
    g = p.add_argument_group('ROS topic')
    g.add_argument('--temp-topic', help='sensor_msgs/Temperature topic (optional)')
    g.add_argument('--mag-topic', help='sensor_msgs/MagneticField topic, tesla (optional)')
    g = p.add_argument_group('simulation')
    g.add_argument('--speed', type=positive_upto(1e4), default=1.0,
                   help='simulated seconds per wall-clock second (default %(default)s)')
    g.add_argument('--seed', type=SEED, default=0)
    g.add_argument('--pose-error', type=non_negative, default=3.0,
                   help='how far off the simulated person holds each pose, degrees')
    g.add_argument('--turn', type=positive, default=2.0,
                   help='seconds the simulated person takes to turn (default %(default)s)')
    g.add_argument('--temp', type=TEMPERATURE, default=25.0,
                   help='simulated temperature, °C')
    g.add_argument('--rate', type=ranged(1.0, 100000.0), default=100.0,
                   help='simulated rate, Hz')
    g.add_argument('--magnetometer', action='store_true',
                   help='the simulated sensor has an AK8963-like magnetometer')


_FACE_ART = {
    'z': ('      ▲ up',
          '  ┌─────────┐',
          '  │ ▪▪ chip │  lying flat, chip side up',
          '  └─────────┘',
          ' ▔▔▔▔▔▔▔▔▔▔▔▔▔'),
    '-z': ('      ▲ up',
           '  ┌─────────┐',
           '  │  bottom │  lying flat, upside down',
           '  └─────────┘',
           ' ▔▔▔▔▔▔▔▔▔▔▔▔▔'),
}


def _axis_arrow(component):
    """Arrow for how far an axis points up: component of the up direction on it."""
    deg = math.degrees(math.asin(max(-1.0, min(1.0, component))))
    if deg > 60:
        return '↑', f'{deg:+.0f}° up'
    if deg > 15:
        return '↗', f'{deg:+.0f}° up'
    if deg >= -15:
        return '→', 'level'
    if deg >= -60:
        return '↘', f'{-deg:.0f}° down'
    return '↓', f'{-deg:.0f}° down'


def board_drawing(direction):
    """
    Return a small text drawing of the board held in the pose ``direction``.

    A side view of the board for the two flat poses; for the others the board stands on
    an edge or a corner, drawn standing, with the side that faces up named. Below it,
    for each sensor axis, an arrow and the angle its + end makes with the horizontal.

    :param direction: (3,) gravity direction of the pose (the sensor axis pointing up).
    :return: multi-line string.
    """
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    up = [('+' if d[i] > 0 else '-') + 'xyz'[i] for i in range(3) if abs(d[i]) > 0.3]
    if abs(d[2]) > 0.95:
        lines = list(_FACE_ART['z' if d[2] > 0 else '-z'])
    else:
        side = ' '.join(up)
        stand = ' on its edge' if abs(d[2]) < 0.3 else ', leaning'
        how = {2: '  tilted 45°', 3: '  on a corner'}.get(len(up), '')
        lines = ['      ▲ up',
                 f'    ┌──┐  {side} side{"s" if len(up) > 1 else ""} up',
                 '    │▪▪│  board standing' + stand,
                 '    │  │' + how,
                 '    └──┘',
                 ' ▔▔▔▔▔▔▔▔▔▔▔▔▔']
    for i, axis in enumerate('xyz'):
        arrow, words = _axis_arrow(d[i])
        lines.append(f'  {axis} axis {arrow} {words}')
    return '\n'.join(lines)


def render(session, source_label, message=''):
    """
    Build the rich renderable of the guide screen.

    :param session: GuideSession.
    :param source_label: where the samples come from.
    :param message: a status line.
    """
    from rich.console import Group
    from rich.panel import Panel
    from rich.progress_bar import ProgressBar
    from rich.table import Table
    from rich.text import Text

    st = session.status()
    adv = st['advice']
    grid = Table.grid(padding=(0, 2))
    grid.add_column(justify='right', style='bold')
    grid.add_column()
    d = st['direction']
    grid.add_row('gravity now', f'({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f})  '
                                f'{pose_name(d)}')
    if st['angle_deg'] is not None:
        on = st['angle_deg'] < 12.0
        grid.add_row('pose asked', Text(f'{st["angle_deg"]:.0f}° from it'
                                        + ('  ✓ on target' if on else ''),
                                        style='green' if on else 'yellow'))
    state = {'moving': 'moving', 'settling': 'settling…', 'holding': 'hold still…',
             'captured': 'captured ✓ — turn to the next pose'}[st['state']]
    if adv.enough:
        state = 'captured ✓ — done'
    bar = Table.grid(padding=(0, 1))
    bar.add_row(ProgressBar(total=1.0, completed=st['progress'], width=30),
                f'{st["progress"] * 100:3.0f} %  {state}')
    grid.add_row('hold', bar)
    grid.add_row('windows', f'{st["windows"]} collected, {st["distinct"]} distinct directions'
                            f' ({session.method} needs {MIN_WINDOWS[session.method]})')
    if adv.predicted_accuracy is None:
        acc = Text(f'— (not solvable yet)  target {adv.target:.4f} m/s²', style='dim')
    else:
        good = adv.predicted_accuracy <= adv.target
        acc = Text(f'{adv.predicted_accuracy:.4f} m/s²  target {adv.target:.4f} m/s²',
                   style='bold green' if good else 'bold yellow')
    grid.add_row('predicted accuracy', acc)
    _imu_rows(grid, session.imu_status)
    parts = [grid]
    if adv.enough:
        parts.append(Panel(Text('ENOUGH — the calibration meets the target', style='bold green'),
                           border_style='green'))
    elif adv.next_pose is not None:
        after = adv.next_pose.predicted_accuracy_after
        title = f'next pose: {adv.next_pose.name}'
        if after is not None:
            title += f'  (then {after:.4f} m/s²)'
        parts.append(Panel(Text(board_drawing(adv.next_pose.gravity_direction)),
                           title=title, title_align='left', border_style='cyan'))
    if message:
        parts.append(Text(message))
    if not adv.enough:
        parts.append(Text('q: stop without writing', style='dim'))
    return Panel(Group(*parts), title=f'accel-calib guide — {source_label}',
                 title_align='left')


def _imu_rows(grid, status):
    """Add the gyroscope's turns and the magnetometer's sphere coverage to the screen."""
    from rich.text import Text
    gyro = status.get('gyroscope')
    if gyro is not None and gyro['status'] != 'absent':
        ok = gyro['status'] == 'ok'
        grid.add_row('gyroscope', Text(gyro['advice'], style='green' if ok else 'yellow'))
    mag = status.get('magnetometer')
    if mag is not None:
        grid.add_row('magnetometer', Text(mag['advice'],
                                          style='green' if mag['enough'] else 'yellow'))


class _Keys:
    """Single key presses from a terminal, without waiting for Enter (no-op otherwise)."""

    def __init__(self):
        self.fd = None
        if sys.stdin is not None and sys.stdin.isatty():
            import termios
            import tty
            self.fd = sys.stdin.fileno()
            self.saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def get(self):
        """Return the keys pressed since the last call ('' if none)."""
        if self.fd is None:
            return ''
        import select
        keys = ''
        while select.select([self.fd], [], [], 0)[0]:
            chunk = os.read(self.fd, 32)
            if not chunk:
                break
            keys += chunk.decode(errors='replace')
        return keys

    def close(self):
        """Restore the terminal."""
        if self.fd is not None:
            import termios
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)
            self.fd = None


def files(args):
    """
    Return (calibration file, history or None) of a guide run, checked.

    By default the files the nodes read for ``--sensor`` (``imu_link``: their default),
    ``$ROS_HOME/accel_calib_ros/<sensor>/``; with ``--history`` the sensor is recorded too.

    :raises UsageError: an output would replace an input, a device or each other.
    """
    from ..dataio.calibration_file import default_calibration_path
    from ..dataio.sensor_id import DEFAULT_SENSOR
    output = args.output or default_calibration_path(args.sensor or DEFAULT_SENSOR)
    check_output(output, args.port, what='-o')
    check_output(args.record, args.port, what='--record')
    if args.record and not os.path.isdir(os.path.dirname(os.path.abspath(args.record))):
        raise UsageError(f'accel-calib: --record {args.record}: its folder does not exist')
    if same_file(args.record, output):
        raise UsageError('accel-calib guide: --record and -o must be different files')
    history = None
    if args.history is not None:
        from ..dataio.history import default_history_path
        args.sensor = args.sensor or DEFAULT_SENSOR
        history = args.history or default_history_path(args.sensor)
        check_output(history, args.port, what='--history')
        if any(same_file(history, f) for f in (output, args.record)):
            raise UsageError('accel-calib guide: the history must not be the output or '
                             'the record file')
    return output, history


def run(args, out):
    """Run ``accel-calib guide``; return the exit status."""
    output, history = files(args)
    try:
        from rich.console import Console
        from rich.live import Live
        from rich.text import Text
    except ImportError:
        raise InputError('the guide needs the rich package (pip install rich)') from None
    if args.simulate:
        source = SimulatedSource(args.rate, args.speed, args.seed, args.pose_error, args.turn,
                                 args.temp, args.gravity, magnetometer=args.magnetometer)
        rate = args.rate
    elif args.port:
        source = SerialSource(args.port, args.baud, args.ascii, args.accel_range,
                              args.gyro_range)
        rate = None
    else:
        source = RosSource(args.topic, args.temp_topic, getattr(args, 'mag_topic', None))
        rate = None
    console = Console()
    session, recorded, keys = None, [], _Keys()
    if rate:
        session = GuideSession(rate, args.method, args.target, args.gravity, args.hold)
    start = time.monotonic()
    status, message = 1, ''
    try:
        pending = []
        with Live(console=console, auto_refresh=False, transient=False) as live:
            last_draw = 0.0
            while True:
                t, a, temp = source.read(session)
                if session is None:
                    pending.append((t, a, temp))
                    rate = rate or _rate([p[0] for p in pending])
                    if rate is None:
                        live.update(Text('waiting for samples from ' + source.label),
                                    refresh=True)
                        continue
                    session = GuideSession(rate, args.method, args.target, args.gravity,
                                           args.hold)
                    t, a, temp = (np.concatenate([p[i] for p in pending]) for i in range(3))
                    a = a.reshape(-1, 3)
                    pending = None
                keep = np.all(np.isfinite(a), axis=1)
                gyro, mag = _imu_of(source, len(keep))
                t, a, temp = t[keep], a[keep], temp[keep]
                gyro = None if gyro is None else gyro[keep]
                if args.record:
                    recorded.append((t, a, temp))
                session.update(t, a, temp, gyro, mag)
                if session.enough:
                    live.update(render(session, source.label, 'fitting…'), refresh=True)
                    break
                pressed = keys.get()
                if 'q' in pressed.lower():
                    message = 'stopped: nothing written'
                    live.update(render(session, source.label, message), refresh=True)
                    break
                if args.timeout and time.monotonic() - start > args.timeout:
                    message = f'timed out after {args.timeout:g} s: nothing written'
                    live.update(render(session, source.label, message), refresh=True)
                    break
                now = time.monotonic()
                if now - last_draw > 0.1:
                    live.update(render(session, source.label), refresh=True)
                    last_draw = now
        if session is not None and session.enough:
            status = _finish(session, output, source.label, console, history, args.sensor,
                             args.max_predicted_error)
        else:
            console.print(message or 'stopped: nothing written')
    except KeyboardInterrupt as err:      # Ctrl-C, SIGTERM, SIGHUP (see cli.main)
        console.print('interrupted: nothing written')
        status = 128 + getattr(err, 'signum', 2)
    finally:
        keys.close()
        source.close()
        if args.record and recorded:
            _write_record(args.record, recorded)
    return status


def _imu_of(source, n):
    """Return the rates (n, 3) and magnetometer samples of the source's last read, or None."""
    gyro = getattr(source, 'last_gyro', None)
    if gyro is not None and len(gyro) != n:
        gyro = None
    return gyro, getattr(source, 'last_mag', None)


def _rate(stamp_lists):
    t = np.concatenate(stamp_lists) if stamp_lists else np.zeros(0)
    if len(t) < 50:
        return None
    dt = np.diff(t)
    dt = dt[dt > 0]
    if len(dt) < 25:
        return None
    return 1.0 / float(np.median(dt))


def _finish(session, output, label, console, history=None, sensor=None,
            max_predicted_error=DEFAULT_SETTINGS.max_predicted_error):
    """
    End the session as every front door does: fit, judge, write the calibration, history.

    :return: the exit status: 1 when the fit is refused (nothing written), 2 when a file
        could not be written (the calibration, or the history after it).
    """
    from ..session.finish import HistoryTarget
    from ..session.settings import GUIDE, SI_UNITS
    settings = DEFAULT_SETTINGS.replace(
        max_predicted_error=max_predicted_error, source=f'accel-calib guide ({label})',
        sensor_id=sensor, input_units=SI_UNITS, words=GUIDE)
    outcome = session.finish(settings, output,
                             HistoryTarget(history, sensor) if history else None)
    if not outcome.accepted:
        console.print(f'cannot calibrate: {outcome.refusal}; nothing written')
        return 2 if outcome.cause else 1
    for o in (outcome.gyro, outcome.magnetometer):
        if o.status != 'absent':
            console.print(o.line())
    for line in outcome.carried + outcome.warnings + outcome.notes:
        console.print(line)
    console.print(f'predicted accuracy {outcome.predicted_accuracy:.4f} m/s² (target '
                  f'{session.target:.4f} m/s²) after {len(session.windows)} poses')
    console.print(f'wrote calibration {output}')
    if outcome.history is not None:
        console.print(f'history {outcome.history["db"]}: {outcome.history["windows_added"]} '
                      f'windows and the calibration kept for sensor {sensor} (session '
                      f'{outcome.history["session"]})')
    return 2 if outcome.cause else 0


def _write_record(path, recorded):
    from ..core.samples import Samples
    from ..dataio.recording import write_samples_csv
    t = np.concatenate([r[0] for r in recorded])
    if len(t) < 2:
        return
    a = np.concatenate([r[1] for r in recorded]).reshape(-1, 3)
    temp = np.concatenate([r[2] for r in recorded])
    write_samples_csv(path, Samples(t, a, temp if np.all(np.isfinite(temp)) else None, None))
