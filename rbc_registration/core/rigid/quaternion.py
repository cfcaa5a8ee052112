"""Unit quaternions ``(x, y, z, w)`` (scalar last, tf2's order) and rotation matrices, 2D and 3D.

numpy + scipy only. A 2D rotation (2, 2) is the rotation about z it is in 3D.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

ORTHONORMAL_TOLERANCE = 1e-6  # max |R^T R - I| of a rotation matrix handed in


def matrix_from_quaternion(quaternion: ArrayLike) -> NDArray[np.float64]:
    """The rotation matrix (3, 3) of a unit quaternion ``(x, y, z, w)`` (normalised first).

    :raises ValueError: on a shape other than (4,), NaN/inf or a zero quaternion.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.linalg.norm(q) > 0:
        raise ValueError(f"quaternion must be 4 finite numbers (x, y, z, w), not all zero, got "
                         f"{np.array2string(q, threshold=8)}")
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quaternion_from_matrix(rotation: ArrayLike) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` of a proper rotation matrix, (2, 2) or (3, 3); a 2D
    rotation is embedded as a rotation about z. Sign: ``w > 0`` (or, when ``w == 0``, the first
    non-zero of x, y, z positive), so a rotation always gives the same four numbers.

    :raises ValueError: when ``rotation`` is not a finite (2, 2) or (3, 3) matrix with
        ``max |RᵀR − I| <= ORTHONORMAL_TOLERANCE`` and ``det R > 0``.
    """
    r = _as_rotation3(rotation)
    q = Rotation.from_matrix(r).as_quat()  # scalar last: (x, y, z, w), as tf2
    if np.asarray(rotation).shape == (2, 2):
        q[0] = q[1] = 0.0  # exactly about z
        q /= np.linalg.norm(q)
    for component in (q[3], q[0], q[1], q[2]):
        if component != 0.0:
            if component < 0.0:
                q = -q
            break
    return tuple(float(v) + 0.0 for v in q)  # + 0.0: no -0.0 in files and command lines


def rpy_from_matrix(rotation: ArrayLike) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] of a proper rotation matrix, (2, 2) or (3, 3): fixed axes X, Y, Z
    (REP 103; tf2's ``getRPY``), ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, pitch in [-pi/2, pi/2].
    A 2D rotation is about z: roll = pitch = 0. At pitch = ±pi/2 (gimbal lock) roll is 0 and
    yaw carries the rest.

    :raises ValueError: as :func:`quaternion_from_matrix`.
    """
    r = _as_rotation3(rotation)
    if np.asarray(rotation).shape == (2, 2):
        return 0.0, 0.0, float(np.arctan2(r[1, 0], r[0, 0])) + 0.0
    with warnings.catch_warnings():   # gimbal lock: scipy warns and sets the third angle to 0
        warnings.simplefilter("ignore", UserWarning)
        yaw, pitch, roll = Rotation.from_matrix(r).as_euler("ZYX")   # intrinsic z-y'-x''
    return float(roll) + 0.0, float(pitch) + 0.0, float(yaw) + 0.0


def _as_rotation3(rotation: ArrayLike) -> NDArray[np.float64]:
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape not in ((2, 2), (3, 3)) or not np.all(np.isfinite(r)):
        raise ValueError(f"rotation must be a finite (2, 2) or (3, 3) matrix, got shape {r.shape}")
    error = float(np.max(np.abs(r.T @ r - np.eye(len(r)))))
    if error > ORTHONORMAL_TOLERANCE or np.linalg.det(r) <= 0:
        raise ValueError(f"rotation is not a proper rotation matrix (max |R^T R - I| = "
                         f"{error:.3g}, det = {np.linalg.det(r):.6g})")
    if len(r) == 2:
        r3 = np.eye(3)
        r3[:2, :2] = r
        return r3
    return r
