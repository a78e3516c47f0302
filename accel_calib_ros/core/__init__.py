"""
The science of calibration, ROS-free and file-free: numpy and scipy only.

``accel`` fits the accelerometer (maximum likelihood, Gauss-Newton, ellipsoid,
temperature bands); ``windows`` finds the static windows, offline and streamed;
``accuracy``, ``advice`` and ``acceptance`` predict, advise and decide; ``simulate``
makes sessions of a virtual sensor. Nothing here imports ``dataio``, ``nodes`` or
``cli``: every other floor may import from here.
"""
