"""
The model-gap workflow: where simulation and measurement disagree, and why.

``workflow`` runs it (``diagnose`` on a recording, ``diagnose_windows`` on static
windows, ``held_out_check``); ``model`` is the baseline plus effects it fits,
``effects`` the library of physical effects, ``noise`` the noise of a window mean and
the null law of the gap and the test's power, ``evidence`` and ``probes`` how an effect
or a residual shows in the session, ``agreement`` whether a candidate agrees with all the
evidence, ``pruning`` what the final model no longer supports, ``result`` the verdict in
JSON and words, ``report`` the plots and the Markdown summary. It builds on ``core`` (the
calibration science) and ``dataio`` (files); the command line and the calibration node
use it.
"""

from .workflow import diagnose, diagnose_windows, held_out_check

__all__ = ['diagnose', 'diagnose_windows', 'held_out_check']
