"""
The poses a person can hold, in words, and what a window held in each tells the fit.

Everything is in the sensor frame. A *pose* is named by its gravity direction: the unit
vector along which the accelerometer reads +1 g while the pose is held (the sensor axis
pointing up). The poses a person can hold without a fixture are the 26 of a cube
resting on a table: 6 faces, 12 edges at 45° and 8 corners (:data:`CANDIDATE_POSES`).
numpy only.
"""

import math

import numpy as np

from .constants import G0
from .errors import InputError

_UPPER = np.triu_indices(3)


def _cube_poses():
    """Return the 26 cube poses: faces first (z up, z down, x, y), then edges, corners."""
    faces = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    edges, corners = [], []
    for x in (1, -1, 0):
        for y in (1, -1, 0):
            for z in (1, -1, 0):
                nonzero = abs(x) + abs(y) + abs(z)
                if nonzero == 2:
                    edges.append((x, y, z))
                elif nonzero == 3:
                    corners.append((x, y, z))
    poses = faces + edges + corners
    return tuple(np.array(v, float) / np.linalg.norm(v) for v in poses), tuple(poses)


def _axis_words(code):
    axes = [(('+' if c > 0 else '-') + a) for c, a in zip(code, 'xyz') if c]
    n = len(axes)
    if n == 1:
        sign, axis = axes[0][0], axes[0][1]
        return f'{axis} axis {"up" if sign == "+" else "down"}'
    if n == 2:
        first, second = axes
        if first[0] == '-' and second[0] == '+':
            first, second = second, first
        if first[0] == '+':
            return f'{first[1]} axis up, tilted 45° toward {second}'
        return f'{first} axis up, tilted 45° toward {second}'
    return 'corner: ' + ' '.join(axes) + ' up'


_POSE_VECTORS, _POSE_CODES = _cube_poses()
CANDIDATE_DIRECTIONS = np.array(_POSE_VECTORS)
"""(26, 3) unit gravity directions of the candidate poses: faces, 45° edges, corners."""
CANDIDATE_NAMES = tuple(_axis_words(c) for c in _POSE_CODES)
CANDIDATE_POSES = tuple(zip(CANDIDATE_DIRECTIONS, CANDIDATE_NAMES))
"""(direction (3,), name) of the 26 poses a person can hold: 6 faces, 12 edges, 8 corners."""
FACE_COUNT = 6


def pose_name(direction):
    """
    Words for the pose whose gravity direction (sensor axis up) is ``direction``.

    The nearest of :data:`CANDIDATE_POSES` is named; a direction more than 10° from
    every candidate is prefixed with 'about'.

    :param direction: (3,) vector in the sensor frame (any length > 0).
    :return: e.g. 'z axis up', 'x axis up, tilted 45° toward +y', 'corner: +x +y +z up'.
    """
    v = np.asarray(direction, float).reshape(3)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0.0:
        raise InputError('a pose direction must be a finite non-zero vector')
    cosines = CANDIDATE_DIRECTIONS @ (v / norm)
    best = int(np.argmax(cosines))
    name = CANDIDATE_NAMES[best]
    if cosines[best] < math.cos(math.radians(10.0)):
        name = 'about ' + name
    return name


def fisher_rows(T, directions, gravity=G0):
    """
    Information rows of window means in the 9 ML parameters, per unit noise.

    A window at unit direction ``u`` measures ``y = T (g u) + b``; only the error along
    the ellipsoid normal ``n ∝ T⁻ᵀ u`` informs the parameters (the tangential part is
    absorbed by ``u``), so its Fisher information is ``h hᵀ / σ²`` with ``h = Gᵀ n``.

    :param T: (3, 3) current estimate.
    :param directions: (N, 3) unit gravity directions.
    :return: (N, 9) rows ``h`` (order of ``core.calibration.PARAMETER_NAMES``).
    """
    u = np.asarray(directions, float).reshape(-1, 3)
    n = np.linalg.solve(np.asarray(T, float).T, u.T).T
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rows, cols = _UPPER
    h = np.empty((len(u), 9))
    h[:, :6] = n[:, rows] * gravity * u[:, cols]
    h[:, 6:] = n
    return h
