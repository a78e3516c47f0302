"""
When a board's samples reach the host: the USB-serial transport and the reader, simulated.

For the clock benchmarks and tests (bench/bench_driver.py, test/dataio): a sensor samples
at its own rate; the microcontroller stamps each sample with its µs clock, ``ppm`` fast;
the frame crosses the UART and a USB-serial bridge that delivers bytes in USB frames of
1 ms (``usb``: the bridge's clock is not the sensor's, so the wait for the next USB frame
sweeps slowly through 0..1 ms) or in 64-byte packets flushed every 4 ms (``packets``: an
Uno's ATmega16U2); the reader then wakes up after a short latency and, now and then, after
a scheduling stall of 2-30 ms, and reads everything that has arrived. What comes out is
the reads: which samples each returned and the host time it returned at.
"""

import numpy as np

FRAME_BYTES = 25


def usb_reads(seconds, rate_hz, ppm, rng, transport='usb', d_min_s=0.0003,
              stall_p=0.003, t0_us=4_294_000_000, host0=1.7e9 + 12.345):
    """
    Simulate the reads of a stream.

    :param seconds: length of the stream.
    :param rate_hz: nominal sample rate (the sensor runs 0.13 % slow of it).
    :param ppm: the microcontroller clock's error, parts per million (+: fast).
    :param rng: numpy Generator.
    :param transport: ``usb`` (1 ms USB frames) or ``packets`` (64-byte packets, 4 ms flush).
    :param d_min_s: the smallest transport delay (UART, bridge), s.
    :param stall_p: chance that a read is late by a scheduling stall.
    :return: (t_us (n,) uint32 device stamps, true (n,) host time each sample was taken,
        reads: list of (first, end, host time) of each read; samples first..end-1).
    """
    rate = rate_hz * (1 - 0.0013)                   # the sensor's own oscillator
    n = int(seconds * rate)
    k = np.arange(n)
    true = host0 + k / rate
    t_us = (t0_us + np.round(k / rate * (1 + ppm * 1e-6) * 1e6).astype(np.int64)
            + rng.integers(-2, 3, n)) & 0xFFFFFFFF  # interrupt latency: a few µs
    wire = true + d_min_s
    if transport == 'usb':
        frame = 1e-3                                # the host's USB frames
        phase = rng.uniform(0, frame)
        at_host = np.ceil((wire - phase) / frame) * frame + phase
    else:
        at_host = np.empty(n)
        pending, flush_at, size = [], None, 0
        for i, t in enumerate(wire):
            pending.append(i)
            size += FRAME_BYTES
            flush_at = flush_at if flush_at is not None else t + 0.004
            if size >= 64 or t >= flush_at:
                at_host[pending] = t if size >= 64 else flush_at
                pending, flush_at, size = [], None, 0
        at_host[pending] = wire[-1] + 0.004
        at_host = np.maximum.accumulate(at_host)
    reads = []
    first, t = 0, at_host[0]
    while first < n:
        t = max(t, at_host[first]) + rng.exponential(0.0001)
        if rng.random() < stall_p:
            t += rng.uniform(0.002, 0.03)
        end = int(np.searchsorted(at_host, t, side='right'))
        reads.append((first, end, float(t)))
        t += 30e-6 * (end - first)                  # publishing what was read
        first = end
    return t_us, true, reads


def stamp_reads(t_us, reads, timestamp='device', mapper=None):
    """
    Stamp simulated reads as the serial link does (held until the mapping settled).

    :param t_us: device stamps from :func:`usb_reads`.
    :param reads: reads from :func:`usb_reads`.
    :param timestamp: ``device`` or ``host``.
    :param mapper: a ClockMapper (default: a new one).
    :return: (stamps (n,) s, the Stamper).
    """
    from ..dataio.wire import RawFrame
    from ..dataio.wire.clock import Stamper
    stamper = Stamper(timestamp, mapper)
    out = np.empty(len(t_us))
    held = []
    for first, end, host in reads:
        frames = [RawFrame(0, int(t), ()) for t in t_us[first:end]]
        held.append((first, end, stamper.observe(frames, host)))
        if stamper.ready:
            for a, b, tokens in held:
                out[a:b] = stamper.stamps(tokens)
            held = []
    for a, b, tokens in held:
        out[a:b] = stamper.stamps(tokens)
    return out, stamper


def stamp_quality(stamps, true, d_min_s=0.0003):
    """
    Judge stamps against the true sample times (plus the constant smallest delay).

    :return: dict: ``within_1ms`` (share), ``max_ms``, ``p99_ms``, ``backwards`` (steps not
        forward), ``bunched`` (steps under 45 % of a sample period), ``spacing`` (min, max of
        the steps over the sample period).
    """
    err = stamps - true - d_min_s
    steps = np.diff(stamps)
    period_s = float(np.median(np.diff(true)))
    return {'within_1ms': float(np.mean(np.abs(err) < 1e-3)),
            'max_ms': float(np.max(np.abs(err)) * 1e3),
            'p99_ms': float(np.percentile(np.abs(err), 99) * 1e3),
            'backwards': int(np.sum(steps <= 0)),
            'bunched': int(np.sum(steps < 0.45 * period_s)),
            'spacing': (float(np.min(steps) / period_s), float(np.max(steps) / period_s))}
