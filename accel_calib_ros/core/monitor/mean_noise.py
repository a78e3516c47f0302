"""
The noise of a still period's mean, from the data's own spectrum (batch means of blocks).

White noise would give a period of ``n`` samples a mean with variance ``σ²/n``; real
MEMS noise is correlated (flicker), and on real recordings long means scatter 1.5-3.5
times more (in standard deviation). Like the model-gap workflow's batch means
(``modelgap.noise``, which the core may not import), :class:`MeanNoise` measures it:
each still period that is a rest adds its block means along gravity, grouped into
batches of ``m`` blocks (``SCALES``), and the Allan variance of adjacent batch means is
compared with what the within-block variance says for white noise. The ratio
``R(m)`` is 1 for white noise and grows like ``a + β m`` for a flicker floor (whose Allan
variance does not fall with averaging); pooled over every period seen, ``a`` and ``β``
are fitted by weighted least squares (``var R(m) = 2 R² / pairs``), and a period of
``K`` blocks gets ``R = a + (β + one standard error) K``, at least ``MIN_RATIO``. Until
``MIN_PAIRS`` block pairs have been seen, a prior stands: ``PRIOR_RATIO`` (3.5², the
worst seen on the real recordings) for means of ``PRIOR_BLOCKS`` blocks or more,
less for shorter ones (linearly from 1: flicker matters more the longer the mean).
"""

import math

import numpy as np

SCALES = (1, 2, 4, 8, 16, 32)
"""Batch lengths, blocks."""
MIN_PAIRS = 50
"""Adjacent block pairs needed before the measured ratio replaces the prior."""
PRIOR_RATIO = 3.5 ** 2
"""Variance ratio assumed before that (real recordings: up to 3.5x in std)."""
PRIOR_BLOCKS = 300
"""... for means of this many blocks or more (30 s of 0.1 s blocks)."""
MIN_RATIO = 0.25
"""Smallest variance ratio believed (vibration that averages out within a block)."""
MAX_RATIO = 1e4
"""Largest variance ratio believed."""


class MeanNoise:
    """Pooled batch-means ratios of the rests seen (see the module docstring)."""

    def __init__(self):
        self.observed = np.zeros(len(SCALES))
        self.expected = np.zeros(len(SCALES))
        self.pairs = np.zeros(len(SCALES))
        self._fit = None

    def add(self, run):
        """Add the blocks of a still period that is a rest (:class:`~.blocks.Run`)."""
        blocks = run.blocks
        if len(blocks) < 2:
            return
        u = run.up()
        y = np.array([float(u @ b.a_mean) for b in blocks])
        n = np.array([float(b.n) for b in blocks])
        v = np.array([float((u * u) @ b.a_var) for b in blocks])
        for i, m in enumerate(SCALES):
            k = len(y) // m
            if k < 2:
                break
            nn = n[:k * m].reshape(k, m)
            count = nn.sum(axis=1)
            mean = (y[:k * m].reshape(k, m) * nn).sum(axis=1) / count
            var = (v[:k * m].reshape(k, m) * nn).sum(axis=1) / count
            white = var / count
            self.observed[i] += 0.5 * float(np.sum(np.diff(mean) ** 2))
            self.expected[i] += 0.5 * float(np.sum(white[:-1] + white[1:]))
            self.pairs[i] += k - 1
        self._fit = None

    def ratio(self, blocks):
        """Return the variance of a mean over ``blocks`` blocks over the white-noise value."""
        if self.pairs[0] < MIN_PAIRS:
            return 1.0 + (PRIOR_RATIO - 1.0) * min(float(blocks) / PRIOR_BLOCKS, 1.0)
        a, beta, beta_sd = self.fit()
        value = a + max(beta + beta_sd, 0.0) * float(blocks)
        return min(max(value, MIN_RATIO), MAX_RATIO)

    def fit(self):
        """Return (a, β, standard error of β) of ``R(m) = a + β m`` (β 0 with one scale)."""
        if self._fit is not None:
            return self._fit
        ok = (self.pairs >= 5) & (self.expected > 0)
        m = np.array(SCALES, float)[ok]
        r = self.observed[ok] / self.expected[ok]
        if len(m) == 0:
            self._fit = (1.0, 0.0, 0.0)
            return self._fit
        w = self.pairs[ok] / (2.0 * np.maximum(r, MIN_RATIO) ** 2)
        if len(m) == 1:
            self._fit = (float(r[0]), 0.0, 1.0 / math.sqrt(float(w[0])) / m[0])
            return self._fit
        A = np.array([[w.sum(), (w * m).sum()], [(w * m).sum(), (w * m * m).sum()]])
        b = np.array([(w * r).sum(), (w * m * r).sum()])
        cov = np.linalg.inv(A)
        a, beta = cov @ b
        self._fit = (float(a), float(beta), math.sqrt(max(float(cov[1, 1]), 0.0)))
        return self._fit

    def summary(self):
        """Return a JSON-ready dict: the measured ratios per batch length and the fit."""
        ok = self.expected > 0
        ratios = {f'{m}_blocks': float(self.observed[i] / self.expected[i])
                  for i, m in enumerate(SCALES) if ok[i] and self.pairs[i] >= 5}
        a, beta, sd = self.fit()
        return {'block_pairs': int(self.pairs[0]), 'batch_ratio': ratios,
                'white_part': a, 'flicker_per_block': beta, 'flicker_per_block_se': sd,
                'prior': bool(self.pairs[0] < MIN_PAIRS)}
