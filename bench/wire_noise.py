"""
A noisy serial link for the frame benchmarks: clean frames, damage, and the score.

Written independently of the parser: the damage is applied to the encoded byte stream and
the score compares what the parser published with what was sent, frame by frame.

Damage models (``kind``):

- ``bits``: every bit flipped with probability ``rate``;
- ``bytes``: every byte XORed with a random non-zero byte with probability ``rate``;
- ``drops``: every byte dropped with probability ``rate``;
- ``inserts``: a random byte inserted before every byte with probability ``rate``;
- ``bursts``: on average one burst per ``1/rate`` frames, replacing 5..50 consecutive bytes
  with random bytes (line noise).

A sent frame is *intact* when all its bytes arrived unchanged and contiguous (a byte inserted
between two frames leaves both intact). A published frame that is not a sent frame is
*garbage*; garbage whose version, flags, ``seq`` and ``t_us`` equal those of a sent frame
is the format's *floor* (a check-value collision in the frame's data; interface spec 1b),
the rest is *other garbage* (the version-2 target: at most 1 per 10^7 frames).
"""

import numpy as np


def make_frames(n, version, rng, period_us=1000, t0=4_294_000_000, mag_every=0):
    """
    Return ``n`` frames (uniformly random axes, plausible temperature) and their bytes.

    :param version: 1 or 2.
    :param mag_every: version 2: every this many frames carries a magnetometer block (0: none).
    :return: (list of RawFrame, bytes, numpy array of frame sizes).
    """
    from accel_calib_ros.dataio.wire import encode, RawFrame
    counts = rng.integers(-32768, 32768, (n, 7))
    counts[:, 3] = 1335 + rng.integers(-30, 31, n)              # about 25 °C
    mags = rng.integers(-4000, 4000, (n, 3))
    frames = []
    for k, row in enumerate(counts.tolist()):
        t_us = (t0 + period_us * k) & 0xFFFFFFFF
        if version == 1:
            frames.append(RawFrame(k & 0xFF, t_us, tuple(row)))
        else:
            mag = None
            if mag_every and k % mag_every == 0:
                mag = tuple(mags[k].tolist()) + (0x10,)
            frames.append(RawFrame(k & 0xFFFF, t_us, tuple(row), mag, 2))
    pieces = [encode(f) for f in frames]
    return frames, b''.join(pieces), np.array([len(p) for p in pieces])


def corrupt(data, sizes, kind, rate, rng, burst=(5, 50)):
    """
    Damage a byte stream.

    :param data: the clean stream (bytes).
    :param sizes: size of each frame in it, bytes (numpy int array).
    :param kind: ``bits``, ``bytes``, ``drops``, ``inserts`` or ``bursts``.
    :param rate: probability per bit/byte, or bursts per frame.
    :return: (damaged bytes, boolean array: frame k damaged).
    """
    buf = np.frombuffer(data, np.uint8).copy()
    n = len(buf)
    frame_of = np.repeat(np.arange(len(sizes)), sizes)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    damaged = np.zeros(len(sizes), bool)
    if kind == 'bits':
        flips = rng.binomial(8 * n, rate)
        where = np.unique(rng.integers(0, 8 * n, flips))
        np.bitwise_xor.at(buf, where // 8, (1 << (where % 8)).astype(np.uint8))
        damaged[frame_of[where // 8]] = True
        return buf.tobytes(), damaged
    if kind == 'bytes':
        hit = np.flatnonzero(rng.random(n) < rate)
        buf[hit] ^= rng.integers(1, 256, len(hit)).astype(np.uint8)
        damaged[frame_of[hit]] = True
        return buf.tobytes(), damaged
    if kind == 'drops':
        gone = rng.random(n) < rate
        damaged[frame_of[gone]] = True
        return buf[~gone].tobytes(), damaged
    if kind == 'inserts':
        before = np.flatnonzero(rng.random(n) < rate)          # insert before byte j
        inside = before[before != starts[frame_of[before]]]    # not at a frame's first byte
        damaged[frame_of[inside]] = True
        noise = rng.integers(0, 256, len(before)).astype(np.uint8)
        return np.insert(buf, before, noise).tobytes(), damaged
    if kind == 'bursts':
        count = rng.binomial(len(sizes), rate)
        where = rng.integers(0, n, count)
        lengths = rng.integers(burst[0], burst[1] + 1, count)
        for s, length in zip(where.tolist(), lengths.tolist()):
            e = min(s + length, n)
            buf[s:e] = rng.integers(0, 256, e - s).astype(np.uint8)
            damaged[frame_of[s]:frame_of[e - 1] + 1] = True
        return buf.tobytes(), damaged
    raise ValueError(f'unknown damage {kind!r}')


def score(sent, published, damaged):
    """
    Compare what the parser published with what was sent.

    :return: dict with ``published``, ``garbage``, ``floor``, ``other_garbage``,
        ``duplicates``, ``intact``, ``intact_lost`` and ``lost_next_to_damage`` (intact
        frames lost that have a damaged neighbour).
    """
    index = {f: k for k, f in enumerate(sent)}
    headers = {(f.version, f.mag is not None, f.seq, f.t_us) for f in sent}
    garbage = [f for f in published if f not in index]
    floor = sum((f.version, f.mag is not None, f.seq, f.t_us) in headers for f in garbage)
    got = [index[f] for f in published if f in index]
    seen = np.zeros(len(sent), bool)
    seen[got] = True
    intact = ~damaged
    lost = intact & ~seen
    neighbour = np.zeros(len(sent), bool)
    neighbour[1:] |= damaged[:-1]
    neighbour[:-1] |= damaged[1:]
    return {'published': len(published), 'garbage': len(garbage), 'floor': floor,
            'other_garbage': len(garbage) - floor, 'duplicates': len(got) - int(seen.sum()),
            'intact': int(intact.sum()), 'intact_lost': int(lost.sum()),
            'lost_next_to_damage': int((lost & neighbour).sum())}


def run_parser(data, chunk=4096, **options):
    """Feed ``data`` in chunks to a fresh FrameParser; return (published, parser)."""
    from accel_calib_ros.dataio.wire import FrameParser
    parser = FrameParser(**options)
    out = []
    for k in range(0, len(data), chunk):
        out += parser.feed(data[k:k + chunk])
    out += parser.flush()
    return out, parser
