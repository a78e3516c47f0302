"""
The model-gap workflow: where simulation and measurement disagree, and why.

``workflow`` runs it (``diagnose`` on a recording, ``diagnose_windows`` on static
windows, ``held_out_check``); ``model`` is the baseline plus effects it fits,
``effects`` the library of physical effects, ``setfit`` the joint fits of sets of them,
``criterion`` the one criterion that compares sets, ``selection`` the model selection,
``steps`` the named effects as steps, ``noise`` the noise of a window mean and the null
law of the gap, ``power`` the naming simulated on the session's design, ``evidence`` and
``probes`` how an effect or a residual shows in the session, ``agreement`` the still data
and the jumps in time that effects are checked by, ``pruning`` what the noise and the
probes say after the selection, ``result`` the verdict in JSON and words, ``report`` the
plots and the Markdown summary. ``effect`` is what every effect is (the one class all
derive from), ``walk`` the offset's random walk. It builds on ``core`` (the calibration
science) and ``dataio`` (files); the command line, the calibration node and the simulator
use it.

The workflow is imported when first asked for: the effect library alone (``effects``, for
the simulator) costs numpy only.
"""

__all__ = ['diagnose', 'diagnose_windows', 'held_out_check']


def __getattr__(name):
    """Import the workflow on first use of ``diagnose``, ``diagnose_windows``, ...."""
    if name in __all__:
        from . import workflow
        return getattr(workflow, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
