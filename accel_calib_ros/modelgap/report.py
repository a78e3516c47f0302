"""
Model-gap report: PNG plots a person looks at, and a short Markdown summary.

``write_report(result, folder)`` writes, for a DiagnoseResult:

- ``gap.png``: the gap after each step (1 = measurement and model agree);
- ``residuals_step<k>.png``: the normalised residuals of the model before step k
  (and of the final model) against temperature, time and orientation;
- ``probes.png``: where the final residual lives (smooth in time, temperature,
  direction and |y|, each with its significance);
- ``report.md``: what was found, the evidence, the plots.

Every file is written atomically.
"""

import os

import matplotlib
import numpy as np

from .effects import G0
from ..dataio.atomic import atomic_write_text
from ..dataio.figures import save_figure

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402, I100


def _residual_figure(path, fit, model_label, c, directions):
    """
    Plot one model's normalised residuals against the session's variables.

    Panels: temperature (if recorded), time, the z component of the gravity direction,
    and the variable the residuals follow most closely (``diagnose.where_variables``).
    Colour:
    the axis nearest vertical; filled when it points up, hollow when down.
    """
    from .evidence import where_variables
    r = fit.residuals
    variables = where_variables(c, directions)
    best, best_r = 'temperature', 0.0
    for name, values in variables.items():
        if np.ptp(values) > 0 and np.ptp(r) > 0:
            rv = float(np.corrcoef(r, values)[0, 1])
            if abs(rv) > abs(best_r):
                best, best_r = name, rv
    panels = [('temperature - mean, °C', c.temp), ('time - mean, s', c.time),
              ('z component of gravity direction', directions[:, 2]),
              (f'{best} (strongest, r = {best_r:+.2f})', variables[best])]
    panels = [p for p in panels if np.ptp(p[1]) > 0]     # no temperature recorded: no panel
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.8), sharey=True,
                             squeeze=False)
    axes = axes[0]
    nearest = np.argmax(np.abs(directions), axis=1)
    up = directions[np.arange(len(directions)), nearest] > 0
    for ax, (label, x) in zip(axes, panels):
        for axis, colour in enumerate(('tab:red', 'tab:green', 'tab:blue')):
            for sign, face in ((True, colour), (False, 'none')):
                mine = (nearest == axis) & (up == sign)
                ax.scatter(x[mine], r[mine], facecolors=face, edgecolors=colour, s=16,
                           label=f'{"+" if sign else "-"}{"xyz"[axis]} nearest up')
        ax.axhline(0, color='k', lw=0.8)
        for band in (-2, 2):
            ax.axhline(band, color='grey', lw=0.6, ls='--')
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel('(|a| - g) / noise')
    axes[0].legend(fontsize=7, loc='best', ncol=2)
    fig.suptitle(f'{model_label}: gap {fit.gap:.2f}')
    save_figure(fig, path)


def _probe_figure(path, result):
    """
    Plot where the final residual lives: each nonparametric probe's smooth over its variable.

    Time, temperature and |y|: the residual (m/s², dots) and the probe's fitted smooth
    (crosses). Direction: the smooth on a longitude/latitude map of the gravity direction.
    Each panel's title gives the probe's p-value (significant below ``PROBE_P``).
    """
    from .model import Model
    from .probes import PROBE_P
    probes = result.probes
    if not probes:
        return False
    fit = result.fits[-1]
    rho, _ = Model(result.baseline, fit.effects).residual_parts(fit.x, result.conditions)
    fig, axes = plt.subplots(1, len(probes), figsize=(4 * len(probes), 3.6), squeeze=False)
    labels = {'time': 'time - mean, s', 'temperature': 'temperature - mean, °C',
              'magnitude': '|raw reading|'}
    for ax, (name, probe) in zip(axes[0], probes.items()):
        mark = 'significant' if probe['p'] < PROBE_P else 'not significant'
        smooth_mg = 1000.0 * probe['_smooth'] / G0
        if name == 'direction':
            d = probe['_x']
            lon, lat = np.degrees(np.arctan2(d[:, 1], d[:, 0])), np.degrees(np.arcsin(d[:, 2]))
            art = ax.scatter(lon, lat, c=smooth_mg, cmap='coolwarm', s=30)
            fig.colorbar(art, ax=ax, label='smooth, mg')
            ax.set_xlabel('longitude of gravity, °')
            ax.set_ylabel('latitude, °')
        else:
            ax.scatter(probe['_x'], 1000.0 * rho / G0, s=10, color='grey', label='residual')
            ax.scatter(probe['_x'], smooth_mg, s=14, marker='x', color='tab:red',
                       label='smooth')
            ax.set_xlabel(labels.get(name, name))
            ax.set_ylabel('|a| - g, mg')
            ax.legend(fontsize=7)
        ax.set_title(f'{name}: p = {probe["p"]:.1e} ({mark})', fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle('Where the final residual lives (nonparametric probes)')
    save_figure(fig, path)
    return True


def write_report(result, folder):
    """Write the plots and report.md of a DiagnoseResult into ``folder`` (created)."""
    from .model import Model
    os.makedirs(folder, exist_ok=True)
    c = result.conditions
    labels = [result.baseline] + [f'+ {name}' for name in result.missing_effects]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    gaps = [fit.gap for fit in result.fits]
    ax.bar(range(len(gaps)), gaps, color=['tab:red'] + ['tab:blue'] * (len(gaps) - 1))
    ax.axhline(1.0, color='k', ls='--', lw=0.8)
    ax.set_xticks(range(len(gaps)), labels, rotation=20)
    ax.set_ylabel('gap = sqrt(chi²/dof)')
    ax.set_yscale('log')
    save_figure(fig, os.path.join(folder, 'gap.png'))

    images = []
    for k, fit in enumerate(result.fits):
        model = Model(result.baseline, fit.effects)
        a = model.true_accel(fit.x, c)
        directions = a / np.linalg.norm(a, axis=1, keepdims=True)
        name = f'residuals_step{k}.png'
        label = ' '.join(labels[:k + 1]) if k else f'baseline {result.baseline}'
        _residual_figure(os.path.join(folder, name), fit, label, c, directions)
        images.append((label, name))

    lines = ['# Model-gap report', '',
             f'Baseline **{result.baseline}**, {result.windows} static windows. '
             f'Gap {result.gap_before:.2f} → {result.gap_after:.2f} '
             '(sqrt of χ²/dof of the gravity-norm residuals, each divided by the noise of its '
             'window measured from the data; about 1 when model and measurement agree).', '']
    if result.steps:
        lines += ['| step | effect | gap before | gap after | F | p | size |',
                  '|---|---|---|---|---|---|---|']
        for k, step in enumerate(result.steps, 1):
            ev = step['evidence']
            lines.append(f'| {k} | {step["effect"]} | {step["gap_before"]:.2f} | '
                         f'{step["gap_after"]:.2f} | {ev["F"]:.1f} | {ev["p"]:.1e} | '
                         f'{ev["magnitude"]} |')
        lines.append('')
        for step in result.steps:
            where = ', '.join(f'{w["variable"]} (r = {w["r"]:+.2f})' for w in step['where'])
            lines.append(f'- **{step["effect"]}**: {step["evidence"]["description"]}. '
                         f'Before adding it the residuals followed {where}.')
    else:
        lines.append('No missing effect is supported by this session.')
    for note in result.ambiguities:
        lines.append(f'- Note: {note}')
    for name, reason in result.skipped.items():
        lines.append(f'- Not testable with this session: {name} ({reason}).')
    for item in result.partial:
        lines.append(f'- Not named: {item["effect"]} (up to {item["worst_case_mg"]:.2g} mg) '
                     f'{item["reason"]}.')
    for item in result.vetoed:
        lines.append(f'- Not named: {item["effect"]} (up to {item["worst_case_mg"]:.2g} mg): '
                     f'{item["reason"]}.')
    for item in result.unconfirmed:
        lines.append(f'- Not named with baseline {result.baseline}: {item["effect"]} '
                     f'({item["reason"]}).')
    if result.candidates:
        lines += ['', f'Candidates of the last round (practical threshold '
                  f'{result.threshold_mg:.2g} mg):', '',
                  '| effect | F | p | worst case, mg | significant | large enough |',
                  '|---|---|---|---|---|---|']
        for cand in result.candidates:
            lines.append(f'| {cand["effect"]} | {cand["F"]:.1f} | {cand["p"]:.1e} | '
                         f'{cand["worst_case_mg"]:.2g} | {"yes" if cand["significant"] else "no"}'
                         f' | {"yes" if cand["large_enough"] else "no"} |')
    lines.append('')
    lines.append(f'Final gap {result.gap_after:.2f}; noise alone gives at most '
                 f'{result.null_limit:.2f} (99.9 % point of F(dof, noise dof), p = '
                 f'{result.null_p:.2g}): {result.verdict()}.')
    lines.append(result.power_text().replace('power:', 'Power:', 1) + '.')
    if result.null_gaps:
        lines.append(f'Re-simulated gaps: {np.mean(result.null_gaps):.2f} ± '
                     f'{np.std(result.null_gaps):.2f} ({len(result.null_gaps)} runs).')
    probes = _probe_figure(os.path.join(folder, 'probes.png'), result)
    if probes:
        lines += ['', '| probe | terms | p | RMS, mg | significant |', '|---|---|---|---|---|']
        for name, probe in result.probes.items():
            lines.append(f'| {name} | {probe["terms"]} | {probe["p"]:.1e} | '
                         f'{probe["rms_mg"]:.2g} | {"yes" if probe["significant"] else "no"} |')
        lines += ['', '![where the residual lives](probes.png)']
    noise = result.noise()
    if 'sample_std' in noise:
        lines.append('')
        lines.append('Noise measured in the windows: per-sample std '
                     + ', '.join(f'{v:.3g}' for v in noise['sample_std'])
                     + f' (reading units), window-mean variance factor {noise["inflation"]:.3g}'
                     + f' ({", ".join(noise.get("model", []))})'
                     + (', white-noise density ' + ', '.join(
                         f'{v:.0f}' for v in noise['noise_density_ug_rthz'])
                        + ' µg/√Hz (Allan N: σ(τ) = N/√τ; at the time scale of the windows '
                        + ', '.join(f'{v:.0f}' for v in noise['window_noise_density_ug_rthz'])
                        + ')' if 'noise_density_ug_rthz' in noise else '') + '.')
    lines += ['', '![gap per step](gap.png)', '']
    for label, name in images:
        lines += [f'### Residuals: {label}', '', f'![{label}]({name})', '']
    atomic_write_text(os.path.join(folder, 'report.md'), '\n'.join(lines))
    return os.path.join(folder, 'report.md')
