"""
The session floor: what every front door shares between collecting and the file.

Collect windows (:mod:`.windows`: a typed :class:`~.windows.Window`, the arrays of a
:class:`~.windows.WindowSet`), fit and accept (:func:`.accept.fit_and_accept` returns
an :class:`~.accept.Outcome`: the calibration, the verdict, the refusal with its
advice, the gyroscope and magnetometer outcomes and the message), and persistence
(:mod:`.persist`: save with what the file being replaced carries forward, and the
history). The calibration node, ``accel-calib fit`` and ``accel-calib guide`` are thin
callers of these; a fix to acceptance is made here, once.

May import ``core``, ``dataio`` and ``modelgap``; no ROS, no terminal.
"""
