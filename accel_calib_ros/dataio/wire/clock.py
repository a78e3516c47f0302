"""
Device clock to host clock: the microcontroller's µs stamps placed on the host time line.

A sample made at host time ``t`` carries the device's ``t_us = (t - t0)·(1 + e)`` (``e``:
the device clock's rate error, 0.1-0.3 % for an Uno's ceramic resonator) and reaches the
host at ``t + d``, ``d`` >= the transport's minimum delay, jittered by USB frames, bursts
and scheduling. So ``host − dev`` lies above a straight line whose slope is the rate error
and whose height is the offset (plus the minimum delay): :class:`ClockMapper` fits that
lower envelope and stamps each sample at ``dev + line(dev)``. :class:`Stamper` adds what
a stream needs on top: stamps for a whole read at once, the ``host`` mode, never a stamp
backwards.
"""

import collections

WRAP = 0x100000000
"""The device clock wraps at 2**32 µs."""
MAX_RATE_ERROR = 0.02
"""No microcontroller clock is off by more than 2 % (ceramic resonators: 0.5 %)."""


def _lower_hull(points):
    """Return the lower convex hull of points sorted by x (monotone chain)."""
    hull = []
    for p in points:
        while len(hull) >= 2:
            (ox, oy), (ax, ay) = hull[-2], hull[-1]
            if (ax - ox) * (p[1] - oy) - (ay - oy) * (p[0] - ox) > 0:
                break
            hull.pop()
        hull.append(p)
    return hull


def _decayed(correction, dev):
    """Return a correction (value at ``at``, decay rate) as it stands at ``dev``."""
    corr, at, rate = correction
    if dev <= at or not corr:
        return corr
    left = max(abs(corr) - rate * (dev - at), 0.0)
    return left if corr > 0 else -left


def envelope_line(points, slope=0.0):
    """
    Fit the line under ``points`` that lies highest at their mean x: (height at x = 0, slope).

    That is the linear programme of Moon, Skelly and Towsley (1999) for clock skew from
    one-way delays: maximise ``sum(a + b·x_i)`` with ``a + b·x_i <= y_i``. Its solution is
    the edge of the lower convex hull over the mean x. Upward noise (delays) cannot pull
    it; one point, or points over no span, keep the given ``slope``.

    :param points: (x, y) pairs, x increasing.
    :return: (a, b).
    """
    if len(points) < 2 or points[-1][0] - points[0][0] <= 0:
        return min(y - slope * x for x, y in points), slope
    hull = _lower_hull(points)
    mean_x = sum(x for x, _ in points) / len(points)
    for (x0, y0), (x1, y1) in zip(hull, hull[1:]):
        if x1 >= mean_x:
            b = (y1 - y0) / (x1 - x0)
            return y0 - b * x0, b
    return min(y - slope * x for x, y in points), slope


class ClockMapper:
    """
    Map the microcontroller's µs clock onto host time: rate and offset fitted, no jitter.

    Each read contributes one point, its last sample's ``(dev, host − dev)`` (the
    sample of a read that waited least). The lowest point of each ``block_s`` of device
    time is kept for ``window_s``; at the end of every block the line under them is refitted
    (:func:`envelope_line`): the slope is the device clock's rate error (``drift_ppm``), so
    an Uno's resonator 0.3 % off is tracked, not chased. Stamps are ``dev + line(dev) +
    correction``: after a refit the stamps do not step to the new line; the correction
    (applied line minus new line) decays at ``max_slew`` s/s, or ``|correction| / slew_tau_s``
    when that is faster (at most ``fast_slew``): the slew limits only that correction, never
    the rate (in the first ``young_s`` of an epoch: ``|correction| / young_tau_s``). A
    correction beyond ``step_s`` is applied at once.

    The device clock is unwrapped (uint32 µs). A clock that steps backwards (a device
    restart, a re-plug onto another board) or forward so far that its sample would be
    stamped more than ``jump_s`` after its own arrival (another board whose clock is
    ahead) starts a new epoch (``resets``; ``last_step_s`` says by how much it stepped):
    the old samples keep the old line, the new ones are mapped afresh. After the port was
    reopened (:meth:`reopened`) the first read starts a new epoch also when its newest
    sample would be stamped more than ``jump_s`` before its arrival (a board whose clock is
    behind; what the OS buffer kept meanwhile is older, its newest sample is not). A point
    more than ``jump_s`` below the line (the device ahead of host time: the line was made
    from delayed data, such as a burst that waited in the OS buffer) or all points of the
    last ``shift_s`` above it by more than ``shift_min_s`` (the transport got slower, or the
    device restarted at a later count) drop the older points (``rebases``).

    :param block_s: length of one block, device seconds.
    :param window_s: device seconds of blocks in the fit.
    :param jump_s: a point this far below the line rebases it, s.
    :param max_slew: slowest decay of a correction, s/s.
    :param slew_tau_s: a larger correction decays at |correction| / slew_tau_s.
    :param fast_slew: fastest decay, s/s.
    :param step_s: a larger correction is applied at once, s.
    :param settle_s: host seconds of points the first epoch needs before it is
        :attr:`ready`.
    :param resettle_s: the same for a later epoch (the rate is known by then).
    :param shift_s: device seconds of recent blocks for the upward-shift test.
    :param shift_min_s: all of them this far above the line: the older points go.
    :param young_s: for this many device seconds of an epoch, a correction decays at
        ``|correction| / young_tau_s`` (the first fits improve fast).
    :param young_tau_s: see ``young_s``.
    :param backlog_s: a first read spanning this much device time is a backlog.
    """

    def __init__(self, block_s=0.1, window_s=20.0, jump_s=0.5, max_slew=1e-3,
                 slew_tau_s=1.0, fast_slew=0.05, step_s=1.0, settle_s=1.0, resettle_s=0.25,
                 shift_s=2.0, shift_min_s=0.002, young_s=5.0, young_tau_s=0.3,
                 backlog_s=0.05):
        self.block_s = float(block_s)
        self.window_s = float(window_s)
        self.jump_s = float(jump_s)
        self.max_slew = float(max_slew)
        self.slew_tau_s = float(slew_tau_s)
        self.fast_slew = float(fast_slew)
        self.step_s = float(step_s)
        self.settle_s = float(settle_s)
        self.resettle_s = float(resettle_s)
        self.young_s = float(young_s)
        self.young_tau_s = float(young_tau_s)
        self.backlog_s = float(backlog_s)
        self.shift_s = float(shift_s)
        self.shift_min_s = float(shift_min_s)
        self.resets = 0
        self.rebases = 0
        self.last_step_s = None     # the step that started the newest epoch, s
        self._reopened = False      # the next sample is the first of a new connection
        self.epoch = 0
        self._b_prior = 0.0
        self._rate_known = False    # a fit spanning slew_tau_s or more gave the rate
        self._lines = {}            # epoch -> (host0, a, b, corr, corr_dev, rate)
        self._start_epoch()
        self._last_raw = None

    # -- state ---------------------------------------------------------------------------

    def _start_epoch(self):
        self._last_raw = None
        self._host0 = None          # host time of the epoch's first sample (small floats)
        self._first_host = None
        self._last_host = None
        self._dev = 0.0             # unwrapped device time since the epoch's first sample
        self._points = collections.deque()
        self._block_start = None
        self._block_min = None
        self._line = None           # (a, b): offset at dev = 0 and slope
        self._line_before = None    # the line a rebase dropped, until the next fit
        self._corr = (0.0, 0.0, 0.0)    # correction at dev, and its decay rate
        self._mapped_dev = None     # device time of the newest stamp given in this epoch
        self._backlog = None        # the epoch's first read held a backlog (old samples)

    def reset(self, step_s=None):
        """
        Forget the mapping (the device restarted): a new epoch; the rate is kept.

        :param step_s: where the old mapping would have put the new clock, against the
            sample's arrival, s (+ ahead, - behind), when known.
        """
        self.resets += 1
        self.last_step_s = step_s
        self.epoch += 1
        self._start_epoch()

    def reopened(self):
        """Say that the port was reopened: the device may be another, its clock elsewhere."""
        self._reopened = True

    @property
    def drift_ppm(self):
        """Return the device clock's rate error against host time, ppm (+: it runs fast)."""
        line = self._line
        b = line[1] if line is not None else self._b_prior
        return -b / (1.0 + b) * 1e6

    @property
    def ready(self):
        """
        Whether the epoch's first stamps can be given now.

        At once, unless its first read brought a backlog (``backlog_s`` of samples or more
        that waited, in the OS buffer say): then not before the epoch has seen ``settle_s``
        of host time while the rate is unknown (the lowest delays of a USB link show within
        about a second), ``resettle_s`` once an earlier epoch measured it, so that the
        backlog is placed by its device clock, not at its arrival.
        """
        if self._first_host is None:
            return False
        if not self._backlog:
            return True
        settle = self.resettle_s if self._rate_known else self.settle_s
        return self._last_host - self._first_host >= settle

    # -- input ---------------------------------------------------------------------------

    def observe(self, t_us_list, host_s):
        """
        Take the samples of one read, received at ``host_s``.

        :param t_us_list: device clocks, µs, uint32, in stream order.
        :param host_s: host time of the read, s.
        :return: one token per sample, (epoch, device seconds), for :meth:`stamp`.
        """
        out = []
        if self._reopened and len(t_us_list):
            self._check_reopened(t_us_list[-1], host_s)
        for t_us in t_us_list:
            if self._last_raw is not None:
                delta = ((t_us - self._last_raw) % WRAP) * 1e-6
                ahead = self._ahead(self._dev + delta, host_s) if delta > self.jump_s else 0.0
                if delta > WRAP * 0.5e-6:           # backwards: the device restarted
                    back = delta - WRAP * 1e-6
                    self.reset(self._ahead(self._dev + back, host_s) or back)
                elif ahead > self.jump_s:           # far ahead of its arrival: another clock
                    self.reset(ahead)
                else:
                    self._dev += delta
            if self._last_raw is None:
                self._host0 = self._first_host = host_s
                self._dev = 0.0
            self._last_raw = t_us
            out.append((self.epoch, self._dev))
        if out:
            if self._backlog is None:
                first = next((d for e, d in out if e == self.epoch), self._dev)
                self._backlog = self._dev - first >= self.backlog_s
            self._last_host = host_s
            self._point(self._dev, host_s - self._host0 - self._dev)
        return out

    def _check_reopened(self, newest_t_us, host_s):
        """
        Restart on the first read after a reopen when its newest sample is far behind.

        The newest sample of a read waited least (what the OS buffer kept while the port
        was closed is older, and rightly so): if even it would be stamped more than
        ``jump_s`` before its arrival, the device clock is behind the old one.
        """
        self._reopened = False
        if self._last_raw is None:
            return
        delta = ((newest_t_us - self._last_raw) % WRAP) * 1e-6
        if delta <= WRAP * 0.5e-6:                  # a step back is found sample by sample
            behind = self._ahead(self._dev + delta, host_s)
            if behind < -self.jump_s:
                self.reset(behind)

    def _ahead(self, dev, host_s):
        """Return how far after ``host_s`` the line would stamp device time ``dev``, s."""
        line = self._line or self._line_before
        if line is None or self._host0 is None:
            return 0.0
        return self._host0 + dev + line[0] + line[1] * dev - host_s

    def _point(self, dev, off):
        line = self._line
        if line is not None and off < line[0] + line[1] * dev - self.jump_s:
            self._rebase(dev)                       # the device is ahead of host time
        if self._block_start is None:
            self._block_start, self._block_min = dev, (dev, off)
        elif off < self._block_min[1]:
            self._block_min = (dev, off)
        if self._line is None:
            self._refit(dev, [self._block_min])
        if dev - self._block_start >= self.block_s:
            self._points.append(self._block_min)
            while self._points and self._points[0][0] < dev - self.window_s:
                self._points.popleft()
            self._block_start, self._block_min = dev, (dev, off)
            self._check_shift(dev)
            self._refit(dev, list(self._points))

    def _rebase(self, dev):
        self.rebases += 1
        self._points.clear()
        self._block_start = self._block_min = None
        self._line_before, self._line = self._line, None

    def _check_shift(self, dev):
        """Drop the older points when every recent one lies well above the line."""
        a, b = self._line
        recent = [p for p in self._points if p[0] >= dev - self.shift_s]
        if len(recent) < 3 or len(recent) == len(self._points):
            return
        if min(y - a - b * x for x, y in recent) > self.shift_min_s:
            self.rebases += 1
            self._points = collections.deque(recent)

    def _refit(self, dev, points):
        """Fit the line to ``points``; the stamps already given stay continuous."""
        old = self._line or self._line_before
        at = self._mapped_dev
        applied = self._applied(at) if old is not None and at is not None else None
        a, b = envelope_line(points, old[1] if old is not None else self._b_prior)
        if abs(b) > MAX_RATE_ERROR:         # noise over a short span: keep it plausible
            b = max(-MAX_RATE_ERROR, min(MAX_RATE_ERROR, b))
            a = min(y - b * x for x, y in points)
        self._line = (a, b)
        self._line_before = None
        self._b_prior = b
        if len(points) >= 2 and points[-1][0] - points[0][0] >= self.settle_s:
            self._rate_known = True
        corr = 0.0 if applied is None else applied - (a + b * at)
        if abs(corr) > self.step_s:
            corr = 0.0
        tau = self.young_tau_s if dev < self.young_s else self.slew_tau_s
        rate = min(max(self.max_slew, abs(corr) / tau), self.fast_slew)
        self._corr = (corr, at or 0.0, rate)
        self._lines[self.epoch] = (self._host0, a, b) + self._corr
        for old_epoch in [e for e in self._lines if e < self.epoch - 1]:
            del self._lines[old_epoch]

    def _applied(self, dev):
        """Return the offset the stamps use at ``dev`` (line plus decaying correction)."""
        a, b = self._line or self._line_before
        return a + b * dev + _decayed(self._corr, dev)

    # -- output --------------------------------------------------------------------------

    def stamp(self, token):
        """
        Return the host stamp of a sample from its :meth:`observe` token (None: unknown).

        A token of an older epoch is mapped with that epoch's last line.
        """
        epoch, dev = token
        if epoch == self.epoch and self._line is not None:
            if self._mapped_dev is None or dev > self._mapped_dev:
                self._mapped_dev = dev
            return self._host0 + dev + self._applied(dev)
        saved = self._lines.get(epoch)
        if saved is None:
            return None
        host0, a, b = saved[:3]
        return host0 + dev + a + b * dev + _decayed(saved[3:], dev)

    def update(self, t_us, host_s):
        """
        Map one sample received at ``host_s`` (a read of one sample).

        :param t_us: device clock, µs, uint32 (wraps at 2**32).
        :param host_s: host receive time of the sample, s.
        :return: stamp on the host clock, s.
        """
        return self.stamp(self.observe([t_us], host_s)[0])


class Stamper:
    """
    Stamps for a stream of reads: device-clock mapped (``device``) or receive time (``host``).

    ``device``: :class:`ClockMapper`. ``host``: the read's receive time for its last sample,
    the others spread back by the device clock (bursts do not bunch). Either way a stamp
    never goes backwards and never bunches: a stamp less than half the device time since
    the previous one after it becomes the previous one plus that half (``clamped`` counts
    these: receive-time jitter in ``host`` mode; in ``device`` mode only a device restart or
    a host clock step back), unless it lies more than ``step_back_s`` behind (the host clock
    was set back): then it is kept (``stepped_back``). No stamp lies more than the
    mapping's doubt (``mapper.jump_s``) after the arrival of its read: such a stamp
    becomes the arrival (counted in ``clamped``). Samples without ``t_us`` get the
    receive time (never before the previous stamp).

    :param mode: ``device`` or ``host``.
    :param mapper: ClockMapper (default: a new one).
    """

    def __init__(self, mode='device', mapper=None, step_back_s=1.0):
        self.mode = mode
        self.mapper = mapper or ClockMapper()
        self.step_back_s = step_back_s
        self.clamped = 0
        self.stepped_back = 0
        self._timed = False         # the stream has device times (ASCII lines may not)
        self._prev = None           # (stamp, token) of the last stamp given

    @property
    def ready(self):
        """Whether stamps can be given now without waiting for the mapping to settle."""
        return self.mode != 'device' or not self._timed or self.mapper.ready

    def observe(self, frames, host_s):
        """
        Take the frames of one read; return their tokens for :meth:`stamps`.

        :param frames: RawFrames (``t_us`` may be None).
        :param host_s: host time of the read, s.
        """
        timed = [f.t_us for f in frames if f.t_us is not None]
        self._timed = self._timed or bool(timed)
        tokens = iter(self.mapper.observe(timed, host_s))
        out = []
        for f in frames:
            out.append((next(tokens) if f.t_us is not None else None, host_s))
        if self.mode == 'host':                     # spread back from the last timed one
            last = next((t for t, _ in reversed(out) if t is not None), None)
            out = [(t, host_s if t is None or last is None or t[0] != last[0]
                    else host_s - (last[1] - t[1])) for t, _ in out]
        return out

    def stamps(self, tokens):
        """Return the host stamps of :meth:`observe` tokens, s: never backwards, never bunched."""
        out = []
        prev = self._prev
        for token, host in tokens:
            stamp = None
            if token is not None and self.mode == 'device':
                stamp = self.mapper.stamp(token)
            if stamp is None:
                stamp = host
            if prev is not None:
                least = 0.0 if token is None else 1e-6     # no device clock: equal at worst
                if token is not None and prev[1] is not None and prev[1][0] == token[0]:
                    least = max(0.5 * (token[1] - prev[1][1]), 1e-6)
                if stamp < prev[0] + least:
                    if prev[0] - stamp > self.step_back_s:
                        self.stepped_back += 1              # the host clock was set back
                    else:
                        self.clamped += 1
                        stamp = prev[0] + least
            if stamp > host + self.mapper.jump_s:           # never far after its arrival
                self.clamped += 1
                stamp = host if prev is None else max(host, prev[0] + 1e-6)
            prev = (stamp, token)
            out.append(stamp)
        self._prev = prev
        return out
