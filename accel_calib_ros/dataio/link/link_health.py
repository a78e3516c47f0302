"""
The link's health, judged from two snapshots of a :class:`~.serial_link.SerialLink`.

Pure functions: no clock, no port, no ROS. :func:`assess` says OK, WARN or ERROR with a
one-line reason for the period between two snapshots; :func:`link_values` gives the
``/diagnostics`` values of the link (rates, counters, the firmware's info frame).
"""

import math

from .serial_link import OPEN_GRACE_S

OK, WARN, ERROR = 0, 1, 2
"""Levels, as diagnostic_msgs/DiagnosticStatus numbers them."""


def silence_s(snap):
    """Return the seconds since the last valid frame (or the first opening); inf: never."""
    since = snap['last_frame_at'] if snap['last_frame_at'] is not None \
        else snap['first_open_at']
    return snap['time'] - since if since is not None else math.inf


def _recoveries(snap):
    info = snap['info']
    return info.recoveries if info is not None else 0


def _rate(snap, prev):
    frames = snap['counters']['frames'] - prev['counters']['frames']
    return frames / max(snap['time'] - prev['time'], 1e-3)


def assess(snap, prev, watchdog_s):
    """
    Judge the link over the period from ``prev`` to ``snap``.

    ERROR when not connected (with the reason), when the firmware says it does not stream
    (while it keeps saying so: a status older than the info frame's repetition is stale and
    the silence is reported instead, with what the firmware said), when
    no valid frame came for ``watchdog_s``, when the reader failed in the period, when no
    message could be published in it, or when the link is badly corrupted; WARN while
    waiting for the first frame after opening the port and when frames were lost, CRC
    errors seen, some messages not published, the firmware recovered the sensor or the
    device clock stepped (its mapping restarted) in the period; OK only while frames flow
    cleanly. The node may add ``published``,
    ``publish_errors`` and ``last_publish_error`` to the snapshots.

    :param snap: :meth:`SerialLink.snapshot` now.
    :param prev: the snapshot of the previous period (or one taken at start-up).
    :param watchdog_s: the watchdog's silence limit, s.
    :return: (level, message).
    """
    c, c0 = snap['counters'], prev['counters']
    info = snap['info']
    rate = _rate(snap, prev)
    new_errors = c['crc_errors'] - c0['crc_errors']
    new_lost = c['lost_frames'] - c0['lost_frames']
    recoveries, recoveries0 = _recoveries(snap), _recoveries(prev)
    silence = silence_s(snap)
    if not snap['connected']:
        reason = snap['last_error'] or ('the reader has stopped' if snap.get('stopped')
                                        else 'the port is not open yet')
        return ERROR, f'not connected: {reason}'
    if info is not None and info.status != 0 and snap.get('status_current', True):
        return ERROR, f'firmware: {info.status_text}'
    if silence >= watchdog_s and (snap['last_frame_at'] is not None
                                  or silence >= OPEN_GRACE_S):
        message = f'no valid frame for {silence:.1f} s'
        if snap['watchdog_reopens']:
            message += f' (port reopened {snap["watchdog_reopens"]} times)'
        if info is not None and info.status != 0:     # stale: the link went silent since
            message += (f'; {snap["info_age_s"]:.0f} s ago the firmware said: '
                        f'{info.status_text}')
        return ERROR, message
    if rate <= 0 or silence >= watchdog_s:
        return WARN, ('connected, waiting for the first frame' if snap['last_frame_at'] is None
                      else f'no valid frame for {silence:.1f} s')
    if snap['reader_errors'] > prev['reader_errors']:
        return ERROR, f'serial reader failed and was restarted: {snap["last_reader_error"]}'
    failed = snap.get('publish_errors', 0) - prev.get('publish_errors', 0)
    if failed:
        published = snap.get('published', 0) - prev.get('published', 0)
        return (ERROR if published <= 0 else WARN), (
            f'{failed} messages could not be published in the last period '
            f'({snap.get("last_publish_error", "")}); the driver goes on')
    if snap['binary'] and snap['strict']:
        return ERROR, (f'link badly corrupted (quality {snap["quality"]:.2f}): only frames '
                       'confirmed by both neighbours are published')
    resets = snap.get('clock_resets', 0) - prev.get('clock_resets', 0)
    if resets > 0:
        step = snap.get('clock_step_s')
        return WARN, ('the device clock ' + (f'stepped {step:+.3f} s' if step is not None
                                             else 'restarted')
                      + f' (a restart, or another device): the stamps follow it afresh '
                      f'({snap["clock_resets"]} clock resets so far)')
    if recoveries > recoveries0:
        return WARN, (f'the firmware recovered the sensor {recoveries - recoveries0} times in '
                      f'the last period ({info.recovery_text}); {new_lost} samples lost')
    if new_errors or new_lost:
        message = f'{new_errors} CRC errors, {new_lost} lost frames in the last period'
        frames = c['frames'] - c0['frames']
        if new_lost and frames > 0:
            message += f' ({100.0 * new_lost / (new_lost + frames):.1f} % of the samples)'
        return WARN, message
    return OK, 'streaming'


def link_values(snap, prev):
    """
    Return the link's ``/diagnostics`` values for the period from ``prev`` to ``snap``.

    :return: dict of name -> value (str, int, float or bool), in display order.
    """
    c = snap['counters']
    binary = snap['binary']
    silence = silence_s(snap)
    version = snap.get('version') if binary else None
    values = {'frame_rate_hz': f'{_rate(snap, prev):.1f}', 'frames': c['frames'],
              'frame_version': version if version else ('ascii' if not binary else 'none'),
              'crc_errors': c['crc_errors'], 'lost_frames': c['lost_frames'],
              'gaps_uncounted': c.get('gaps_uncounted', 0),
              'bytes_skipped': c['bytes_skipped'], 'connected': snap['connected'],
              'rejected': c['rejected'], 'reconnects': snap['reconnects'],
              'reader_errors': snap['reader_errors'],
              'watchdog_reopens': snap['watchdog_reopens'],
              'publish_errors': snap.get('publish_errors', 0),
              'frames_held': snap.get('frames_held', 0),
              'info_timeouts': snap.get('info_timeouts', 0),
              'stamps_clamped': snap.get('stamps_clamped', 0),
              'clock_resets': snap.get('clock_resets', 0),
              'clock_last_step_s': 'none' if snap.get('clock_step_s') is None
              else f'{snap["clock_step_s"]:+.3f}',
              'last_frame_age_s': f'{silence:.2f}' if math.isfinite(silence) else 'none',
              'format': snap['format'], 'timestamp': snap['timestamp'], 'port': snap['port'],
              'baud': snap['baud']}
    if binary:
        values['link_quality'] = f'{snap["quality"]:.3f}'
        values['frames_v1'] = c['frames_v1']
        values['frames_v2'] = c['frames_v2']
        values['timing_jitter_frames'] = c['timing_jitter']
        jitter = snap['jitter_us']
        values['timing_jitter_us'] = 'unknown' if jitter is None else f'{jitter:.0f}'
        values['parser_errors'] = c['internal_errors']
        if snap['period_us']:
            values['device_rate_hz'] = f'{1e6 / snap["period_us"]:.1f}'
    info = snap['info']
    if info is not None:
        values.update({'chip': info.chip, 'who_am_i': f'0x{info.who_am_i:02x}',
                       'firmware_status': info.status_text,
                       'firmware_version': f'{info.fw_version[0]}.{info.fw_version[1]}',
                       'firmware_rate_hz': info.rate_hz, 'firmware_baud': info.baud})
        if info.info_version >= 2:
            values.update({'firmware_frame_version': info.frame_version,
                           'firmware_recoveries': info.recoveries,
                           'firmware_i2c_errors': info.i2c_errors,
                           'firmware_last_recovery': info.recovery_text})
    if 'drift_ppm' in snap:
        values['clock_drift_ppm'] = f'{snap["drift_ppm"]:.1f}'
    return values
