"""
Accept or refuse a fitted calibration: the one decision the CLI and the node share.

A fit is refused when it did not converge (unless the caller allows it), when its
predicted accuracy (interface.md §5, m/s² RMS at 1 g over all orientations) is unknown
or worse than the limit, and, when the caller asks, when it is not physical for an
accelerometer in m/s² (scale, cross-axis, bias limits of
:meth:`core.calibration.Calibration.physical_problems`). A refusal for accuracy says what
would fix it, from the fit's own information (:mod:`core.information`, the source of
``advise``): the poses that would lower the predicted accuracy most, never a direction
already held (within 25°); or, when the cause is the cross-axis terms a ``gn`` fit
cannot model, that, and the method that models them.
The words of a front door (its option or parameter names, its hints) come in as arguments
(``session.settings.Words``). numpy only, ROS-free.
"""


from dataclasses import dataclass, field

import numpy as np

from .calibration import MAX_BIAS_G, MAX_CROSS_AXIS, MAX_SCALE_ERROR


@dataclass
class Review:
    """
    Verdict on a fitted calibration.

    ``reasons`` lists why it is refused (most basic first, empty when accepted);
    ``warnings`` what the user should know about an accepted one; ``poses`` (name,
    predicted accuracy m/s² once held or None) the poses a refusal for accuracy names,
    best first; ``cross_axis_cause`` is True when the refusal is the cross-axis terms a
    ``gn`` fit cannot model.
    """

    accepted: bool
    reasons: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    converged: bool = True
    accuracy_ok: bool = True
    physical_problems: list = field(default_factory=list)
    cross_axis_cause: bool = False

    @property
    def refusal(self):
        """One-line reason for the refusal, or None when accepted."""
        return '; '.join(self.reasons) if self.reasons else None


def poses_that_help(cal, count=3):
    """
    Return the poses that would lower the predicted accuracy of ``cal`` most, best first.

    :param cal: Calibration from :func:`core.accelerometer.fit.calibrate` (its
        ``information``); none for a calibration without it.
    :return: list of (name, direction (3,), predicted accuracy once held, m/s², or None).
    """
    from .information import poses_to_add
    if getattr(cal, 'information', None) is None:
        return []
    extra = cal.cross_axis.accuracy if getattr(cal, 'cross_axis', None) is not None else 0.0
    with np.errstate(all='ignore'):
        try:
            return poses_to_add(cal.information, count, extra=extra)
        except (np.linalg.LinAlgError, ValueError):
            return []


def estimation_accuracy(cal):
    """Return the predicted accuracy without the ``gn`` cross-axis allowance, m/s²."""
    acc = cal.predicted_accuracy
    cross = getattr(cal, 'cross_axis', None)
    if acc is None or cross is None or not np.isfinite(acc):
        return acc
    return float(np.sqrt(max(acc ** 2 - cross.accuracy ** 2, 0.0)))


def cross_axis_words(cross, ml_hint='fit with the ml method'):
    """
    Say what the cross-axis terms a ``gn`` fit holds at zero cost, and what to do.

    :param cross: ``core.information.CrossAxis``.
    :param ml_hint: how the front end asks for the 9-parameter method.
    """
    share = f'{cross.accuracy:.3g} m/s² of the predicted error'
    if cross.measured.all():
        ml = (f' (it models them: predicted accuracy {cross.ml_accuracy:.3g} m/s² here)'
              if cross.ml_accuracy is not None and np.isfinite(cross.ml_accuracy) else '')
        return (f'the gn model assumes orthogonal axes, but these windows show cross-axis '
                f'terms up to {cross.largest_deg():.2g}° ({cross.source}), which gn cannot '
                f'model and no pose removes ({share}): {ml_hint}{ml}')
    poses = (': ' + ', then '.join(cross.poses)) if cross.poses else ''
    return (f'the gn model assumes orthogonal axes and these poses cannot show whether they '
            f'are: its cross-axis terms are charged at {cross.source} ({share}); hold '
            f'tilted poses that measure them{poses} (if they are small, gn passes), or '
            f'{ml_hint} (it models them)')


def accuracy_reason(acc, limit, poses, limit_name='', unit='m/s²'):
    """
    One-line reason a predicted accuracy ``acc`` is not good enough, naming poses to add.

    :param acc: predicted accuracy, m/s² (None or non-finite: unknown).
    :param limit: acceptance limit, m/s².
    :param poses: from :func:`poses_that_help`.
    :param limit_name: how the caller spells the limit (option or parameter name; '': none).
    :param unit: spelling of m/s² in the message.
    """
    value = ('unknown' if acc is None or not np.isfinite(acc)
             else f'{acc:.4f} {unit}')
    if poses:
        parts = []
        for name, _, after in poses:
            parts.append(name if after is None or parts and after > limit
                         else f'{name} (predicted accuracy then {after:.3g} {unit})')
            if after is not None and after <= limit:
                break                   # enough once this one is held
        hint = ('; the pose that would help most: ' + ', then '.join(parts)
                + (' - hold it' if len(parts) == 1 else ' - hold each')
                + ' still a few seconds and record again')
    else:
        hint = '; hold more distinct poses (each axis up and down, and tilted) and record again'
    return (f'predicted accuracy {value} is worse than the limit {limit:g} {unit}'
            f'{_named(limit_name)}{hint}')


def _named(name):
    return f' ({name})' if name else ''


def review(cal, max_predicted_error, allow_unconverged=False, refuse_unphysical=False,
           max_scale_error=MAX_SCALE_ERROR, max_cross_axis=MAX_CROSS_AXIS,
           max_bias_g=MAX_BIAS_G, limit_name='', unit='m/s²', ml_hint='fit with the ml method'):
    """
    Decide whether a fitted calibration may be used.

    :param cal: fitted :class:`core.calibration.Calibration` (``predicted_accuracy`` filled).
    :param max_predicted_error: acceptance limit on the predicted accuracy, m/s².
    :param allow_unconverged: accept a fit that did not converge (``Review.converged``
        stays False: the caller says loudly that it is not to be trusted).
    :param refuse_unphysical: refuse a non-physical fit (else it is only a warning).
    :param max_scale_error: limit on ``|T_ii - 1|``.
    :param max_cross_axis: limit on ``|T_ij| / T_ii``.
    :param max_bias_g: limit on a bias, g.
    :param limit_name: name of the limit in the messages (an option, a parameter; '': none).
    :param unit: spelling of m/s² in the messages.
    :param ml_hint: how the front end asks for the 9-parameter method.
    :return: :class:`Review`.
    """
    reasons, warnings = [], []
    converged = bool(cal.converged)
    if not converged and not allow_unconverged:     # allowed: the caller warns loudly
        reasons.append(f'the {cal.method} fit did not converge in {cal.iterations} '
                       'iterations: add more distinct poses')
    acc = cal.predicted_accuracy
    accuracy_ok = acc is not None and bool(np.isfinite(acc)) and acc <= max_predicted_error
    cross = getattr(cal, 'cross_axis', None)
    poses, cross_cause = [], False
    if not accuracy_ok:
        estimation = estimation_accuracy(cal)
        # The cross-axis terms gn cannot model are the cause when they are the larger share.
        cross_cause = cross is not None and estimation is not None and \
            cross.accuracy >= estimation
        if cross_cause:
            value = f'{acc:.4f} {unit}' if np.isfinite(acc) else 'unknown'
            reason = (f'predicted accuracy {value} is worse than the limit '
                      f'{max_predicted_error:g} {unit}{_named(limit_name)}: '
                      + cross_axis_words(cross, ml_hint))
        else:
            poses = poses_that_help(cal)
            reason = accuracy_reason(acc, max_predicted_error, poses, limit_name, unit)
            if cross is not None and cross.accuracy > max_predicted_error:
                reason += '; and ' + cross_axis_words(cross, ml_hint)
        reasons.append(reason)
    problems = cal.physical_problems(max_scale_error, max_cross_axis, max_bias_g)
    if problems and refuse_unphysical:
        reasons.append('not physical: ' + '; '.join(problems) + f' (are the readings in {unit}?)')
    elif problems:
        warnings.extend(f'{problem} (are the data in {unit}?)' for problem in problems)
    if cross is not None and accuracy_ok:
        warnings.append(f'the predicted accuracy includes {cross.accuracy:.3g} {unit} for the '
                        f'cross-axis terms the 6-parameter gn model leaves out, from '
                        f'{cross.source}')
    return Review(accepted=not reasons, reasons=reasons, warnings=warnings,
                  poses=[(name, after) for name, _, after in poses], converged=converged,
                  accuracy_ok=accuracy_ok, physical_problems=problems,
                  cross_axis_cause=cross_cause)
