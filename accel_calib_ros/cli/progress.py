"""
Progress bars for long commands: tqdm on stderr, on a terminal only, after about 2 s.

A short command shows nothing and does not even import tqdm; output piped to a file or
a test never gets a bar. Without tqdm installed the work goes on silently.
"""

import sys
import time

DELAY_S = 2.0
"""Seconds of work before a bar appears (shorter runs stay quiet)."""


class Progress:
    """
    Count work done; show a tqdm bar on stderr once the work has taken ``DELAY_S``.

    Use as a context manager; call ``update(n)`` after each piece of work.

    :param total: units of work expected, or None when unknown.
    :param desc: short label shown before the bar.
    :param unit: name of one unit of work (rows, B, ...).
    :param stream: where the bar goes (default stderr); no bar unless it is a terminal.
    """

    def __init__(self, total=None, desc='', unit='rows', stream=None):
        self.total = total
        self.desc = desc
        self.unit = unit
        self.stream = stream if stream is not None else sys.stderr
        self.done = 0
        self._bar = None
        try:
            self._enabled = self.stream.isatty()
        except (AttributeError, ValueError):
            self._enabled = False
        self._start = time.monotonic()

    def update(self, n):
        """Record ``n`` more units of work done."""
        self.done += n
        if self._bar is not None:
            self._bar.update(n)
        elif self._enabled and time.monotonic() - self._start >= DELAY_S:
            try:
                from tqdm import tqdm
            except ImportError:
                self._enabled = False
                return
            self._bar = tqdm(total=self.total, initial=self.done, desc=self.desc,
                             unit=self.unit, unit_scale=True, file=self.stream, leave=False,
                             dynamic_ncols=True)
            self._bar.start_t -= time.monotonic() - self._start    # time from the start

    def close(self):
        """Remove the bar, if one is shown."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self):
        """Start counting."""
        return self

    def __exit__(self, *exc):
        """Remove the bar."""
        self.close()
        return False
