"""
Simulated hardware for demos and tests: a virtual MPU-9250 and the end-to-end demo.

``device`` streams the serial frames of a simulated sensor on a pseudo-terminal (what
``accel-calib simulate-device`` runs and the driver node reads); ``demo`` runs the whole
chain (virtual sensor or emulated board -> driver -> calibration -> correction) and
reports the error against the truth (``make demo``). The physics of the simulated
sensor is in ``sensor`` (sessions of it in ``motion``), the simulated person in ``person``.
"""
