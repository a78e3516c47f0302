"""
The magnetometer's calibration: hard iron, soft iron, alignment, field and dip (§10).

``fit`` fits them from every magnetometer sample of a session and its static windows.
"""
