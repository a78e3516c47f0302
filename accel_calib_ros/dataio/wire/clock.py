"""
Device clock to host clock: the microcontroller's µs stamps placed on the host time line.

The transport (USB-serial bursts, scheduling) delays each sample by a varying amount;
the lower envelope of (host − device) time is the clock offset, and its slope the drift.
"""


class ClockMapper:
    """
    Map the microcontroller's µs clock onto host time, without the transport jitter.

    The host receives sample k at ``host_k = offset + (1 + drift) * dev_k + delay_k``
    with ``delay_k >= d_min``: the lower envelope of ``host - dev`` is the clock
    offset (plus the constant minimum delay). The device clock is unwrapped (uint32
    µs); ``host - dev`` is reduced to its minimum over blocks of ``block_s`` seconds and
    a straight line is fitted through the last ``blocks`` minima (offset and drift).
    Stamps are ``dev + line(dev)``: the device's own sample spacing, placed on the host
    clock. A device clock that steps backwards, or forward by more than host time
    can explain (``jump_s``), restarts the mapping (``resets`` counts these). After a
    refit the stamps slew to the new line at no more than ``max_slew`` (s/s) instead of
    stepping, unless it moved by more than ``step_s``.

    :param block_s: length of one minimum block, device seconds.
    :param blocks: number of blocks in the fit (window = blocks x block_s).
    :param jump_s: tolerated excess of device time over host time between samples.
    :param max_slew: largest rate of change of the applied offset, s per s.
    :param step_s: a larger change of the fitted offset is applied at once.
    """

    def __init__(self, block_s=2.0, blocks=15, jump_s=0.5, max_slew=1e-3, step_s=0.005):
        self.block_s = float(block_s)
        self.max_slew = float(max_slew)
        self.step_s = float(step_s)
        self.blocks = int(blocks)
        self.jump_s = float(jump_s)
        self.resets = 0
        self.reset()
        self.resets = 0

    def reset(self):
        """Forget the mapping (after a reconnect or a device reset)."""
        self.resets += 1
        self._last_raw = None
        self._last_host = None
        self._dev = 0.0             # unwrapped device time since the first sample, s
        self._host0 = None          # host time of the first sample (keeps floats small)
        self._points = []           # (dev, min offset) of finished blocks
        self._block_start = None
        self._block_min = None
        self._a = 0.0               # offset at dev = 0
        self._b = 0.0               # drift, s/s
        self._applied = 0.0         # offset used for the last stamp
        self._applied_dev = 0.0

    @property
    def drift_ppm(self):
        """Return the estimated device clock rate error, parts per million."""
        return self._b * 1e6

    def update(self, t_us, host_s):
        """
        Map one sample.

        :param t_us: device clock, µs, uint32 (wraps at 2**32).
        :param host_s: host receive time of the sample, s.
        :return: stamp on the host clock, s.
        """
        if self._last_raw is not None:
            delta = ((t_us - self._last_raw) & 0xFFFFFFFF) * 1e-6
            if delta > 2147.483648 or delta > (host_s - self._last_host) + self.jump_s:
                self.reset()
            else:
                self._dev += delta
        if self._last_raw is None:
            self._host0 = host_s
            self._dev = 0.0
        self._last_raw = t_us
        self._last_host = host_s
        dev = self._dev
        offset = (host_s - self._host0) - dev
        if self._block_start is None:
            self._block_start = dev
            self._block_min = (dev, offset)
        elif offset < self._block_min[1]:
            self._block_min = (dev, offset)
        if dev - self._block_start >= self.block_s:
            self._points.append(self._block_min)
            del self._points[:-self.blocks]
            self._block_start = dev
            self._block_min = (dev, offset)
            self._fit()
        elif not self._points:
            self._a = self._block_min[1]
        target = self._a + self._b * dev
        if not self._points or abs(target - self._applied) > self.step_s:
            self._applied = target
        else:                        # slew to a refitted line: no step in the stamps
            limit = self.max_slew * (dev - self._applied_dev)
            self._applied += max(-limit, min(limit, target - self._applied))
        self._applied_dev = dev
        return self._host0 + dev + self._applied

    def _fit(self):
        pts = self._points
        if len(pts) < 3:
            self._a = min(p[1] for p in pts)
            self._b = 0.0
            return
        n = len(pts)
        mx = sum(p[0] for p in pts) / n
        my = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        sxy = sum((p[0] - mx) * (p[1] - my) for p in pts)
        b = sxy / sxx if sxx > 0 else 0.0
        # Under every block minimum (lower envelope): stamps do not run ahead of receipt.
        self._a = min(p[1] - b * p[0] for p in pts)
        self._b = b
