"""
The session floor: what every front door shares between collecting and the file.

Collect windows (:mod:`.windows`: a typed :class:`~.windows.Window`, the arrays of a
:class:`~.windows.WindowSet`); say what the door asks and how it spells it
(:mod:`.settings`: one :class:`~.settings.Settings` holding every default, one
:class:`~.settings.Words` per door); then end the session with one call,
:func:`.finish.finish_session`: fit and accept (:mod:`.accept`: an
:class:`~.accept.Outcome` with the calibration, the verdict, the refusal with its advice,
the gyroscope's and magnetometer's outcomes), save (:mod:`.persist`: with what the file
being replaced carries forward) and the history. The calibration node, ``accel-calib fit``
and ``accel-calib guide`` are thin callers of it; a fix to acceptance is made here, once.

May import ``core``, ``dataio`` and ``modelgap``; no ROS, no terminal.
"""
