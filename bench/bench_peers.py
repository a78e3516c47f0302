"""
The "Real recordings" table of docs/benchmarks.md: the three public recordings in test/data/peers.

For each recording and method: the windows found, accepted or refused and the words of
the refusal, the fitted numbers beside the peer's own, and the prediction against
held-out data (held-out windows of the same session where it can be split, other
recordings of the sensor where it cannot). Everything is measured here, on the
product's own commands (``accel-calib fit``) and core. Run: ``python bench/bench_peers.py``.
"""

import contextlib
import io
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'test'))

import peer_data  # noqa: E402  (test helper: the recordings and the peers' numbers)

from accel_calib_ros.cli import main  # noqa: E402,I100
from accel_calib_ros.core.accelerometer.fit import calibrate  # noqa: E402
from accel_calib_ros.core.windows import detect_static_windows  # noqa: E402
from accel_calib_ros.dataio.units import to_si  # noqa: E402

G0 = 9.80665


def fit(path, *options):
    """Run ``accel-calib fit --json``; return (exit status, summary, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(['fit', str(path), '--json', *options])
    text = out.getvalue().strip()
    return code, json.loads(text) if text else {}, err.getvalue().strip()


def verdict(code, err):
    if code == 0:
        return 'accepted'
    return 'refused: ' + err.split('cannot calibrate: ', 1)[-1]


def held(cal, windows, rate):
    r = peer_data.held_out(cal, windows, rate)
    return f'{r["measured"]:.4f} vs {r["predicted"]:.4f} ({r["windows"]} windows)'


def main_table():
    folder = tempfile.mkdtemp()
    imu_tk = peer_data.to_spec_csv(peer_data.imu_tk(), os.path.join(folder, 'imu_tk.csv'))
    mpu = peer_data.to_spec_csv(peer_data.mpu6050(counts=True), os.path.join(folder, 'm.csv'))
    imucal = peer_data.to_spec_csv(peer_data.imucal_ferraris()[0],
                                   os.path.join(folder, 'imucal.csv'))
    raw = peer_data.to_spec_csv(peer_data.imucal_annotated()[0], os.path.join(folder, 'r.csv'))
    tk = ['--counts-per-g', '4065', '--counts-offset', '32768', '--gravity', '9.81744']

    print('== imu_tk (Xsens MTi, raw unsigned counts; ' + ' '.join(tk) + ')')
    for method in ('ml', 'gn'):
        code, s, err = fit(imu_tk, *tk, '--method', method)
        print(f'  {method}: {s.get("observations")} windows, predicted '
              f'{s.get("predicted_accuracy"):.4f} m/s², {verdict(code, err)}')
    code, s, _ = fit(imu_tk, *tk)
    k = G0 / 4065.0
    ref = peer_data.IMU_TK_REFERENCE
    print(f'  ml inverse scales {np.round(np.array(s["scale"]) / k, 3).tolist()} counts/(m/s²)'
          f' (imu_tk {ref["inverse_scale"].tolist()}), bias '
          f'{np.round(32768 + np.array(s["bias"]) / k, 1).tolist()} counts '
          f'(imu_tk {ref["bias"].tolist()})')
    samples = to_si(peer_data.imu_tk(), 'counts', 4065.0, 32768.0)
    w = detect_static_windows(samples)
    even = np.arange(len(w)) % 2 == 0
    for name, train in (('even', even), ('odd', ~even)):
        part = w.select(train)
        cal = calibrate(part.mean, peer_data.IMU_TK_GRAVITY, 'ml',
                        part.weights(5.0, samples.rate_hz), noise_std=part.noise_std)
        print(f'  ml fitted on the {name} windows: held-out |a|-g RMS measured vs predicted '
              f'{held(cal, w.select(~train), samples.rate_hz)} m/s²')

    print('== MPU-6050 (tomisuarez2, raw ±2 g counts; --range 2)')
    for method in ('ml', 'gn'):
        code, s, err = fit(mpu, '--range', '2', '--method', method)
        print(f'  {method}: {s.get("observations")} windows, predicted '
              f'{s.get("predicted_accuracy"):.4f} m/s², {verdict(code, err)}')
    code, s, _ = fit(mpu, '--range', '2', '--max-predicted-error', '1')
    k = G0 / 16384.0
    ref = peer_data.MPU6050_REFERENCE
    print(f'  ml (forced) scale {np.round(k / np.array(s["scale"]) * 1e4, 4).tolist()}e-4 '
          f'(m/s²)/count (authors {np.round(ref["scale"] * 1e4, 4).tolist()}e-4), bias '
          f'{np.round(-np.array(s["bias"]) / k, 1).tolist()} counts (authors, their sign: '
          f'{np.round(ref["bias"], 1).tolist()})')
    samples = peer_data.mpu6050()
    w = detect_static_windows(samples)
    cal = calibrate(w.mean, G0, 'ml', w.weights(5.0, samples.rate_hz), noise_std=w.noise_std)
    for which in ('still', 'static_test', 'rotation_test'):
        other = peer_data.mpu6050(which)
        print(f'  ml (forced), held-out recording {which}: |a|-g RMS measured vs predicted '
              f'{held(cal, detect_static_windows(other), other.rate_hz)} m/s²')

    print('== imucal Ferraris session (m/s²)')
    for method in ('ml', 'gn'):
        code, s, err = fit(imucal, '--method', method)
        acc = s.get('predicted_accuracy')
        print(f'  {method}: {s.get("observations")} windows, predicted '
              + (f'{acc:.4f} m/s²' if acc is not None else '-') + f', {verdict(code, err)}')
    samples = peer_data.imucal_ferraris()[0]
    w = detect_static_windows(samples)
    first = w.t_mid < np.median(w.t_mid)
    cal = calibrate(w.mean[first], 9.81, 'gn', w.weights(5.0, samples.rate_hz)[first],
                    noise_std=w.noise_std)
    print(f'  gn (forced) on the six-face phase, held-out = the later x/y/z-up windows: '
          f'{held(cal, w.select(~first), samples.rate_hz)} m/s²')
    print('== imucal annotated session (raw ±16 g counts; --range 16 --gravity 9.81)')
    code, s, err = fit(raw, '--range', '16', '--gravity', '9.81', '--method', 'gn')
    print(f'  gn: {s.get("observations")} windows, {verdict(code, err)}')
    code, s, _ = fit(raw, '--range', '16', '--gravity', '9.81', '--method', 'gn',
                     '--max-predicted-error', '1')
    k = G0 / 2048.0
    _, ref = peer_data.imucal_annotated()
    print(f'  gn (forced) K_a {np.round(np.array(s["scale"]) / k, 3).tolist()} counts/(m/s²) '
          f'(imucal {np.round(ref["K_a"], 3).tolist()}), b_a '
          f'{np.round(np.array(s["bias"]) / k, 2).tolist()} counts '
          f'(imucal {np.round(ref["b_a"], 2).tolist()}); no held-out split: each half lacks '
          'faces')


if __name__ == '__main__':
    main_table()
