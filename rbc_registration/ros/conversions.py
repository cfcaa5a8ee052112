"""Message <-> numpy conversions for ``registration_node``. No model math here: only copying
fields, frame checks and the 2D <-> 3D embedding (dimension 2 uses x, y; z passes through).

Units: metres (REP 103). A ``Registration`` maps ``destination ≈ R @ working + t``.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PointStamped, TransformStamped, Vector3
from numpy.typing import NDArray

from rbc_registration_interfaces.msg import FiducialResidual, TargetCorrection

from ..core.constants import UNCORRECTED
from ..core.measurements.checks import stamp_seconds
from ..core.measurements.records import quote
from ..core.validation import MAX_ABS_COORDINATE
from ..pipeline.ingest import PairArgs
from . import fast_msgs


def stamp_to_seconds(stamp: Time) -> float:
    """``builtin_interfaces/Time`` -> seconds (float).

    :raises RejectedMeasurement: ``malformed`` when ``nanosec`` is 10^9 or more
        (:func:`~rbc_registration.core.measurements.checks.stamp_seconds`).
    """
    return stamp_seconds(stamp.sec, stamp.nanosec)


def nanoseconds_to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> ``builtin_interfaces/Time``."""
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def point_to_array(point: Point) -> NDArray[np.float64]:
    """``geometry_msgs/Point`` -> array (3,)."""
    return np.array((point.x, point.y, point.z), dtype=np.float64)


def array_to_point(xyz: Sequence[float]) -> Point:
    """(3,) -> ``geometry_msgs/Point``."""
    return fast_msgs.point(float(xyz[0]), float(xyz[1]), float(xyz[2]))


def array_to_vector3(xyz: Sequence[float]) -> Vector3:
    """(3,) -> ``geometry_msgs/Vector3``."""
    return fast_msgs.vector3(float(xyz[0]), float(xyz[1]), float(xyz[2]))


def fiducial_pair_to_args(msg: Any) -> PairArgs:
    """``rbc_registration_interfaces/FiducialPair`` -> :class:`PairArgs` (empty id -> None;
    group and session as sent)."""
    w, d = msg.working_point, msg.destination_point
    return PairArgs(msg.fiducial_id or None, (w.x, w.y, w.z), (d.x, d.y, d.z), msg.header.frame_id,
                    msg.destination_frame_id, stamp_to_seconds(msg.header.stamp), msg.group,
                    msg.session)


def point_stamped_to_tuple(msg: PointStamped) -> tuple[tuple[float, float, float], str, float]:
    """``geometry_msgs/PointStamped`` -> ((x, y, z), frame_id, stamp [s])."""
    p = msg.point
    return (p.x, p.y, p.z), msg.header.frame_id, stamp_to_seconds(msg.header.stamp)


def targets_to_array(targets: Sequence[PointStamped], working_frame: str,
                     dimension: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Targets -> (points (K, dimension) for the model, z (K,) to pass through in 2D).

    :raises ValueError: naming the first target whose frame is not ``working_frame`` (an empty
        frame_id means the working frame), or in 2D whose z is NaN, inf or beyond ±1e12.
    """
    for k, target in enumerate(targets):
        frame = target.header.frame_id
        if frame and frame != working_frame:
            raise ValueError(f"target {k} has frame_id {quote(frame)}, expected the working frame "
                             f"{working_frame!r} (or empty)")
    xyz = np.array([point_to_array(t.point) for t in targets], dtype=np.float64).reshape(-1, 3)
    if dimension == 2:
        # z is not seen by the 2D model but passed through to the answer: check it here (x, y
        # are checked by the model like every coordinate in 3D).
        bad = np.flatnonzero(~(np.abs(xyz[:, 2]) <= MAX_ABS_COORDINATE))
        if bad.size:
            k = int(bad[0])
            raise ValueError(f"target {k} has z = {float(xyz[k, 2])!r}: coordinates must be "
                             f"finite and within ±{MAX_ABS_COORDINATE:g} (dimension 2 passes z "
                             "through)")
    return xyz[:, :dimension], xyz[:, 2].copy()


def _to_xyz(points: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K, 2|3) -> (K, 3): in 2D, append ``z`` (targets' z passes through unchanged)."""
    if points.shape[1] == 3:
        return points
    return np.column_stack([points, z])


def target_corrections_to_msgs(tc: Any, z: NDArray[np.float64], method: str,
                               destination_frame: str, stamps: Sequence[Time],
                               label: str = "") -> list[TargetCorrection]:
    """``core.model.TargetCorrections`` -> one ``TargetCorrection`` message per target.

    :param z: the targets' z, used in 2D for the destination points (passed through).
    :param method: the decision's method (``tc.destination`` is its point; ``uncorrected``:
        no correction applied).
    :param stamps: the targets' stamps, copied into the answers.
    :param label: the ``method`` field when not ``method`` itself (e.g. ``kriging
        (calibration file)``).
    """
    # Whole arrays to Python floats once (tolist is exact), then messages built by fast_msgs.
    corrected = _to_xyz(np.asarray(tc.corrected), z).tolist()
    uncorrected = _to_xyz(np.asarray(tc.uncorrected), z).tolist()
    destination = _to_xyz(np.asarray(tc.destination), z).tolist()
    correction = _to_xyz(np.asarray(tc.correction), np.zeros_like(z)).tolist()
    inside = np.asarray(tc.inside_hull, dtype=bool).tolist()
    expected = np.asarray(tc.expected_error, dtype=np.float64).tolist()
    tre = np.asarray(tc.expected_tre, dtype=np.float64).tolist()
    bound = np.asarray(tc.tre_bound, dtype=np.float64).tolist()
    applied = method != UNCORRECTED
    out = []
    for k in range(len(z)):
        c = fast_msgs.point_stamped(stamps[k], destination_frame, fast_msgs.point(*corrected[k]))
        u = fast_msgs.point_stamped(stamps[k], destination_frame,
                                    fast_msgs.point(*uncorrected[k]))
        d = u if not applied else fast_msgs.point_stamped(stamps[k], destination_frame,
                                                          fast_msgs.point(*destination[k]))
        out.append(fast_msgs.target_correction(d, c, u, fast_msgs.vector3(*correction[k]),
                                               applied, inside[k], expected[k],
                                               label or method, tre[k], bound[k]))
    return out


def _point3(xyz: Sequence[float]) -> Point:
    """d coordinates (2 or 3) -> ``geometry_msgs/Point`` (z = 0 in 2D)."""
    return fast_msgs.point(*(list(map(float, xyz)) + [0.0] * (3 - len(xyz))))


def fiducial_residual_msg(r: Any) -> FiducialResidual:
    """``pipeline.residuals.FiducialResidual`` -> ``FiducialResidual`` message (metres)."""
    f = r.summary
    return FiducialResidual(
        fiducial_id=f.fiducial_id, enabled=f.enabled, n_measurements=f.n_measurements,
        correction_norm=r.correction_norm, cv_error=r.cv_error,
        cv_error_uncorrected=r.cv_error_uncorrected, residual_uncorrected=r.residual_uncorrected,
        working_mean=_point3(f.working_mean), destination_mean=_point3(f.destination_mean))


def fill_correct_target_response(response: Any, result: TargetCorrection) -> Any:
    """Copy a ``TargetCorrection`` into a ``CorrectTarget`` response (success=True)."""
    for name in fast_msgs.FIELDS[TargetCorrection]:
        setattr(response, name, getattr(result, name))
    response.success = True
    return response


def rotation_to_quaternion(rotation: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """A proper 3x3 rotation matrix -> unit quaternion (x, y, z, w), w >= 0 (Shepperd's method)."""
    r = np.asarray(rotation, dtype=np.float64)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s)
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[k, k], 1e-300))
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (r[j, i] + r[i, j]) / s
        v[k] = (r[k, i] + r[i, k]) / s
        q = (v[0], v[1], v[2], (r[k, j] - r[j, k]) / s)
    n = math.sqrt(sum(c * c for c in q))
    q = tuple(c / n for c in q)
    return q if q[3] >= 0 else tuple(-c for c in q)  # type: ignore[return-value]


def embed_3d(rotation: NDArray[np.float64],
             translation: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A 2D registration as a 3D one (rotation about z, z unchanged); 3D passes through."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    if r.shape == (3, 3):
        return r, t
    r3 = np.eye(3)
    r3[:2, :2] = r
    return r3, np.array([t[0], t[1], 0.0])


def registration_to_transform(registration: Any, parent_frame: str, child_frame: str,
                              stamp: Time) -> TransformStamped:
    """``Registration`` (destination ≈ R @ working + t) -> ``TransformStamped`` with
    ``header.frame_id = parent_frame`` (destination) and ``child_frame_id = child_frame``
    (working): the pose of the working frame in the destination frame, as tf expects."""
    r, t = embed_3d(registration.rotation, registration.translation)
    msg = TransformStamped()
    msg.header.frame_id = parent_frame
    msg.header.stamp = stamp
    msg.child_frame_id = child_frame
    msg.transform.translation = array_to_vector3(t)
    x, y, z, w = rotation_to_quaternion(r)
    msg.transform.rotation.x, msg.transform.rotation.y = x, y
    msg.transform.rotation.z, msg.transform.rotation.w = z, w
    return msg


def transform_to_matrix(msg: TransformStamped) -> NDArray[np.float64]:
    """``TransformStamped`` -> 4x4 homogeneous matrix (for tests and clients)."""
    q = msg.transform.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = (msg.transform.translation.x, msg.transform.translation.y,
                msg.transform.translation.z)
    return m
