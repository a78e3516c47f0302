"""
Model-gap report of one still pose while the temperature sweeps: heating against cooling.

``write_still_report(result, folder)`` writes, for a ``still.StillResult``:

- ``offsets.png``: each axis's offset (bin means less their pose's constant, mg) against
  the reported temperature, heating and cooling in two colours, with the baseline's curve;
- ``hysteresis.png``: what each model leaves (mg) against temperature, heating and
  cooling, before (the baseline: the offset against the reported temperature) and after
  the named effects;
- ``held_out.png``: the same for a leg predicted from the other (fit on heating, predict
  cooling), when the recording holds both;
- ``report.md``: the verdict, the steps, the held-out gaps and the plots.

Every file is written atomically.
"""

import os

import matplotlib
import numpy as np

from .still_pose import StillModel
from ..dataio.atomic import atomic_write_text
from ..dataio.figures import save_figure

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402, I100

STILL_REPORT_FILES = ('report.md', 'offsets.png', 'hysteresis.png', 'held_out.png')
"""Files the one-pose report may write."""

LEG_STYLE = ((1, 'tab:red', 'heating'), (-1, 'tab:blue', 'cooling'), (0, 'grey', 'steady'))


def _legs_scatter(ax, temp, values, legs):
    for sign, colour, label in LEG_STYLE:
        mine = legs == sign
        if mine.any():
            ax.scatter(temp[mine], values[mine], s=6, color=colour, label=label)


def _offsets_figure(path, result):
    """Plot the offsets against temperature per axis, heating and cooling, with the curve."""
    c = result.conditions
    base = StillModel(c, [])
    x = result.fits[0].x
    k, p = base.per_axis, c.design.pose_cols.shape[1]
    mg = 1000.0 / c.gravity
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    order = np.argsort(c.temp_abs)
    for i, ax in enumerate(axes):
        constant = c.design.pose_cols @ x[i * k:i * k + p]
        _legs_scatter(ax, c.temp_abs, (c.readings[:, i] - constant) * mg, c.legs)
        curve = c.design.node_cols @ x[i * k + p:(i + 1) * k]
        ax.plot(c.temp_abs[order], curve[order] * mg, color='k', lw=1.2,
                label='offset against temperature')
        ax.axvline(c.reference_c, color='k', ls=':', lw=0.8)
        ax.set_xlabel('reported temperature, °C')
        ax.set_ylabel(f'{"xyz"[i]} offset, mg')
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Offsets of one still pose (zero at the calibration's {c.reference_c:.1f} °C)")
    save_figure(fig, path)


def _rest_figure(path, result):
    """Plot what the baseline and the final model leave, against temperature, per leg."""
    c = result.conditions
    mg = 1000.0 / c.gravity
    rows = [('baseline (offset against the reported temperature)', result.fits[0])]
    if len(result.fits) > 1:
        rows.append(('+ ' + ', '.join(result.missing_effects), result.fits[-1]))
    fig, axes = plt.subplots(len(rows), 3, figsize=(13, 3.4 * len(rows)), squeeze=False)
    for row, (label, fit) in zip(axes, rows):
        rest = (fit.residuals * c.flat_sigma).reshape(3, -1).T * mg
        for i, ax in enumerate(row):
            _legs_scatter(ax, c.temp_abs, rest[:, i], c.legs)
            ax.axhline(0.0, color='k', lw=0.8)
            ax.set_title(f'{label}: {"xyz"[i]}', fontsize=9)
            ax.set_xlabel('reported temperature, °C')
            ax.set_ylabel('left, mg')
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle('Heating against cooling: what each model leaves')
    save_figure(fig, path)


def _held_out_figure(path, result):
    """Plot a leg predicted from the other, before and after the named effects."""
    c = result.conditions
    mg = 1000.0 / c.gravity
    if (c.legs > 0).sum() < 10 or (c.legs < 0).sum() < 10:
        return False
    train, test = c.legs > 0, c.legs < 0
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    models = [([], 'tab:grey', 'baseline')]
    if result.missing_effects:           # else the baseline alone (not drawn twice as "+ ")
        models.append((result.fits[-1].effects, 'tab:green',
                       '+ ' + ', '.join(result.missing_effects)))
    for effects, colour, label in models:
        model = StillModel(c, effects)
        rest = (c.flat_readings - model.matrix() @ model.fit_rows(train)).reshape(3, -1).T[test] \
            * mg
        for i, ax in enumerate(axes):
            ax.scatter(c.temp_abs[test], rest[:, i], s=6, color=colour, label=label)
    for i, ax in enumerate(axes):
        ax.axhline(0.0, color='k', lw=0.8)
        ax.set_xlabel('reported temperature, °C')
        ax.set_ylabel(f'{"xyz"[i]}: cooling predicted from heating, mg')
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle('Held out: the cooling bins predicted by a fit on the heating bins')
    save_figure(fig, path)
    return True


def write_still_report(result, folder):
    """Write the plots and report.md of a StillResult into ``folder`` (created)."""
    os.makedirs(folder, exist_ok=True)
    c = result.conditions
    _offsets_figure(os.path.join(folder, 'offsets.png'), result)
    _rest_figure(os.path.join(folder, 'hysteresis.png'), result)
    held = _held_out_figure(os.path.join(folder, 'held_out.png'), result)
    low, high = c.rec.temp_range_c
    lines = ['# Model-gap report: one still pose while the temperature sweeps', '',
             f'{len(c)} bins, {low:.1f} .. {high:.1f} °C, {int((c.legs > 0).sum())} heating and '
             f'{int((c.legs < 0).sum())} cooling; the baseline is the offset of each axis '
             f'against the reported temperature (zero at {c.reference_c:.1f} °C). Gap '
             f'{result.gap_before:.2f} → {result.gap_after:.2f} (about 1 when model and '
             'measurement agree).', '']
    if result.steps:
        lines += ['| step | effect | gap before | gap after | p | size |',
                  '|---|---|---|---|---|---|']
        for k, step in enumerate(result.steps, 1):
            ev = step['evidence']
            lines.append(f'| {k} | {step["effect"]} | {step["gap_before"]:.2f} | '
                         f'{step["gap_after"]:.2f} | {ev["p"]:.1e} | {ev["magnitude"]} |')
        lines.append('')
        for step in result.steps:
            lines.append(f'- **{step["effect"]}**: {step["evidence"]["description"]}.')
    else:
        lines.append('No missing effect is supported by this recording.')
    for note in result.ambiguities:
        lines.append(f'- Note: {note}')
    for name, reason in result.skipped.items():
        lines.append(f'- Not testable with this recording: {name} ({reason}).')
    for name, entry in (result.held_out or {}).items():
        before, after = entry['baseline'], entry['with_effects']
        lines.append(f'- Held out, {name.replace("_", " ")} ({entry["bins"]} bins): gap '
                     f'{before["gap"]:.2f} → {after["gap"]:.2f}; RMS per axis '
                     + ', '.join(f'{a:.2f} → {b:.2f}'
                                 for a, b in zip(before['rms_mg'], after['rms_mg']))
                     + ' mg.')
    lines += ['', f'Verdict: {result.verdict()}.', '', '![offsets](offsets.png)', '',
              '![heating against cooling](hysteresis.png)', '']
    if held:
        lines += ['![held out](held_out.png)', '']
    atomic_write_text(os.path.join(folder, 'report.md'), '\n'.join(lines))
    return os.path.join(folder, 'report.md')
