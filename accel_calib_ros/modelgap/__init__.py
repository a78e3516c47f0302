"""
The model-gap workflow: where simulation and measurement disagree, and why.

``workflow`` runs it (``diagnose`` on a recording, ``diagnose_windows`` on static
windows, ``held_out_check``); ``model`` is the baseline plus effects it fits,
``effects`` the library of physical effects, ``setfit`` the joint fits of sets of them,
``criterion`` the one criterion that compares sets, ``selection`` the model selection,
``steps`` the named effects as steps, ``noise`` the noise of a window mean and the null
law of the gap, ``power`` the naming simulated on the session's design, ``evidence`` and
``probes`` how an effect or a residual shows in the session, ``agreement`` the
measurements that can contradict one effect (the still data, a walk's roughness),
``pruning`` what the noise and the probes say after the selection, ``result`` the verdict
in JSON and words, ``report`` the plots and the Markdown summary. It builds on ``core`` (the
calibration science) and ``dataio`` (files); the command line and the calibration node
use it.
"""

from .workflow import diagnose, diagnose_windows, held_out_check

__all__ = ['diagnose', 'diagnose_windows', 'held_out_check']
