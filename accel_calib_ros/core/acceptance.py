"""
Accept or refuse a fitted calibration: the one decision the CLI and the node share.

A fit is refused when it did not converge (unless the caller allows it), when its
predicted accuracy (spec section 5, m/s² RMS at 1 g over all orientations) is unknown
or worse than the limit, and, when the caller asks, when it is not physical for an
accelerometer in m/s² (scale, cross-axis, bias limits of
:meth:`core.model.Calibration.physical_problems`). The refusal names the faces (axis
up/down) the poses do not pin down, from :func:`core.accuracy.worst_faces`.
Checks that only make sense in one front end (the node's residual-to-noise ratio, the
CLI's ``--force`` wording) stay there. numpy only, ROS-free.
"""

from dataclasses import dataclass, field

import numpy as np

GN_MIN_POSES = 10
"""Below this many poses a 6-parameter ``gn`` fit cannot show the cross-axis error."""


@dataclass
class Review:
    """
    Verdict on a fitted calibration.

    ``reasons`` lists why it is refused (most basic first, empty when accepted);
    ``warnings`` what the user should know about an accepted one; ``missing_faces``
    (name, predicted error m/s²) the faces the poses do not pin down.
    """

    accepted: bool
    reasons: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    missing_faces: list = field(default_factory=list)
    converged: bool = True
    accuracy_ok: bool = True
    physical_problems: list = field(default_factory=list)

    @property
    def refusal(self):
        """One-line reason for the refusal, or None when accepted."""
        return '; '.join(self.reasons) if self.reasons else None


def missing_faces(cal, limit, count=3):
    """
    Faces whose predicted error exceeds ``limit`` (or is unknown), worst first.

    :param cal: fitted Calibration (T, covariance, gravity).
    :param limit: acceptance limit, m/s².
    :param count: at most this many faces.
    :return: list of (name, predicted RMS error m/s², nan when unknown).
    """
    from .accuracy import worst_faces
    try:
        with np.errstate(all='ignore'):
            faces = worst_faces(cal.T, cal.covariance, cal.gravity)
    except (np.linalg.LinAlgError, ValueError, TypeError):
        return []
    return [(name, err) for name, _, err in faces if not err <= limit][:count]


def accuracy_reason(acc, limit, faces, limit_name='max_predicted_error', unit='m/s²'):
    """
    One-line reason a predicted accuracy ``acc`` is not good enough.

    :param acc: predicted accuracy, m/s² (None or non-finite: unknown).
    :param limit: acceptance limit, m/s².
    :param faces: from :func:`missing_faces`.
    :param limit_name: how the caller spells the limit (option or parameter name).
    :param unit: spelling of m/s² in the message.
    """
    value = ('unknown' if acc is None or not np.isfinite(acc)
             else f'{acc:.4f} {unit}')
    if faces:
        hint = ('; the poses do not pin the calibration down for: '
                + ', '.join(f'{name} (predicted error {err:.3g} {unit})' if np.isfinite(err)
                            else name for name, err in faces)
                + ' - hold the sensor that way (still, a few seconds each) and record again')
    else:
        hint = '; hold more distinct poses (each axis up and down) and record again'
    return (f'predicted accuracy {value} is worse than the limit {limit:g} {unit} '
            f'({limit_name}){hint}')


def review(cal, max_predicted_error, allow_unconverged=False, refuse_unphysical=False,
           max_scale_error=0.2, max_cross_axis=0.1, max_bias_g=0.25,
           limit_name='max_predicted_error', unit='m/s²'):
    """
    Decide whether a fitted calibration may be used.

    :param cal: fitted :class:`core.model.Calibration` (``predicted_accuracy`` filled).
    :param max_predicted_error: acceptance limit on the predicted accuracy, m/s².
    :param allow_unconverged: accept a fit that did not converge (``Review.converged``
        stays False: the caller says loudly that it is not to be trusted).
    :param refuse_unphysical: refuse a non-physical fit (else it is only a warning).
    :param max_scale_error: limit on ``|T_ii - 1|``.
    :param max_cross_axis: limit on ``|T_ij| / T_ii``.
    :param max_bias_g: limit on a bias, g.
    :param limit_name: name of the limit in the messages (CLI option, node parameter).
    :param unit: spelling of m/s² in the messages.
    :return: :class:`Review`.
    """
    reasons, warnings = [], []
    converged = bool(cal.converged)
    if not converged and not allow_unconverged:     # allowed: the caller warns loudly
        reasons.append(f'the {cal.method} fit did not converge in {cal.iterations} '
                       'iterations: add more distinct poses')
    acc = cal.predicted_accuracy
    accuracy_ok = acc is not None and bool(np.isfinite(acc)) and acc <= max_predicted_error
    faces = [] if accuracy_ok else missing_faces(cal, max_predicted_error)
    if not accuracy_ok:
        reasons.append(accuracy_reason(acc, max_predicted_error, faces, limit_name, unit))
    problems = cal.physical_problems(max_scale_error, max_cross_axis, max_bias_g)
    if problems and refuse_unphysical:
        reasons.append('not physical: ' + '; '.join(problems) + f' (are the readings in {unit}?)')
    elif problems:
        warnings.extend(f'{problem} (are the data in {unit}?)' for problem in problems)
    if cal.method == 'gn' and cal.observations < GN_MIN_POSES:
        warnings.append(f'the 6-parameter gn model assumes orthogonal axes; '
                        f'{cal.observations} poses cannot check that, so the predicted '
                        'accuracy leaves out any cross-axis error (up to ±2 % on an '
                        f'MPU-9250: hold {GN_MIN_POSES} or more poses, or use ml)')
    return Review(accepted=not reasons, reasons=reasons, warnings=warnings,
                  missing_faces=faces, converged=converged, accuracy_ok=accuracy_ok,
                  physical_problems=problems)
