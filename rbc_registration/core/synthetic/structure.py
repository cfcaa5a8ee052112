"""Synthetic cells with structure, in millimetres: fiducials in groups that share an error (a
robot cell measured with a laser tracker, several reflectors per pose) and measurements in
sessions between which the working frame moved (:func:`moved_sessions`).

Robot cell (:func:`make_robot_cell`): poses drawn uniformly over 1.2 m x 1.0 m x 0.6 m,
each carrying 3 or 4 reflectors 60-100 mm from the flange. The destination frame (the robot's
nominal coordinates) holds the true points; the working frame (the tracker) sees each point moved
rigidly, plus the pose's kinematic error, plus noise. The kinematic error of a pose is a smooth
part (a translation and a small rotation of the flange that vary smoothly with the pose's
position: what interpolation can correct) plus a part of its own (backlash, the joint
configuration: shared by the pose's reflectors, unpredictable from other poses). Every target is
a point at a pose of its own, drawn like a fiducial (a reflector where the peg will be).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from .cells import SyntheticCell, _bias_field, random_rotation

#: The robot cell's work volume [mm].
ROBOT_EXTENT = np.array([1200.0, 1000.0, 600.0])


@dataclass(frozen=True)
class RobotCell:
    """A generated robot cell (mm).

    :ivar fiducial_ids, fiducial_groups: one id and the pose (group) of each reflector.
    :ivar working: (J, d) one measurement of each fiducial in the working frame (tracker).
    :ivar destination: (J, d) the fiducials in the destination frame (robot, the truth).
    :ivar target_working: (K, d) targets measured once in the working frame.
    :ivar target_truth: (K, d) the targets in the destination frame.
    """

    fiducial_ids: tuple[str, ...]
    fiducial_groups: tuple[str, ...]
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    target_working: NDArray[np.float64]
    target_truth: NDArray[np.float64]


def _cross(w: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.cross(w, v)


def make_robot_cell(seed: int = 0, poses: int = 36, targets: int = 20,
                    smooth_mm: float = 0.8, own_mm: float = 0.25, noise_mm: float = 0.02
                    ) -> RobotCell:
    """A robot cell (module docstring) with ``poses`` fiducial poses and ``targets`` targets.

    :param smooth_mm: RMS per axis of the smooth part of the kinematic error.
    :param own_mm: RMS per axis of each pose's own error (translation; its rotation gives the
        same at 100 mm).
    :param noise_mm: the tracker's noise per axis.
    """
    rng = np.random.default_rng([seed, 34])
    centres = rng.uniform(0.05, 0.95, size=(poses, 3)) * ROBOT_EXTENT
    target_centres = rng.uniform(0.05, 0.95, size=(targets, 3)) * ROBOT_EXTENT
    smooth_t = _bias_field(rng, 3, ROBOT_EXTENT)
    smooth_w = _bias_field(rng, 3, ROBOT_EXTENT)
    probe = rng.uniform(-1, 1, size=(2000, 3)) * ROBOT_EXTENT
    t_scale = smooth_mm / float(np.sqrt(np.mean(smooth_t(probe) ** 2)))
    w_scale = smooth_mm / 100.0 / float(np.sqrt(np.mean(smooth_w(probe) ** 2)))
    rot = random_rotation(rng, 3)
    trans = rng.uniform(-2000, 2000, size=3)

    def pose_points(centre: NDArray[np.float64], count: int) -> NDArray[np.float64]:
        flange = random_rotation(rng, 3)
        radius = rng.uniform(60.0, 100.0, size=count)
        angle = 2 * np.pi * np.arange(count) / count + rng.uniform(0, 2 * np.pi)
        local = np.stack([radius * np.cos(angle), radius * np.sin(angle),
                          rng.uniform(-20, 20, size=count)], -1)
        return local @ flange.T

    def measured(centre: NDArray[np.float64], offsets: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        truth = centre + offsets
        error = (t_scale * smooth_t(centre[None])[0] + rng.normal(0, own_mm, 3)
                 + _cross(w_scale * smooth_w(centre[None])[0]
                          + rng.normal(0, own_mm / 100.0, 3), offsets))
        work = (truth - trans) @ rot + error + rng.normal(0, noise_mm, truth.shape)
        return work, truth

    ids, groups, work, dest = [], [], [], []
    for p, centre in enumerate(centres):
        count = int(rng.integers(3, 5))
        w, t = measured(centre, pose_points(centre, count))
        for k in range(count):
            ids.append(f"pose{p:02d}_N{k + 1}")
            groups.append(f"pose{p:02d}")
        work.append(w)
        dest.append(t)
    tw, tt = [], []
    for centre in target_centres:
        w, t = measured(centre, pose_points(centre, 1))
        tw.append(w[0])
        tt.append(t[0])
    return RobotCell(tuple(ids), tuple(groups), np.vstack(work), np.vstack(dest),
                     np.array(tw), np.array(tt))


@dataclass(frozen=True)
class SessionCell:
    """A cell measured in two sessions, the working frame moved between them (mm).

    :ivar ids, sessions: per measurement, the fiducial id and its session (``s1``, ``s2``).
    :ivar working: (n, d) the measurements in the working frame of their session.
    :ivar destination: (n, d) the fiducials' destination points (truth), per measurement.
    :ivar target_ids, target_sessions, target_working: the targets' measurements.
    :ivar target_truth: per target id (in order of first appearance), the truth.
    """

    ids: tuple[str, ...]
    sessions: tuple[str, ...]
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    target_ids: tuple[str, ...]
    target_sessions: tuple[str, ...]
    target_working: NDArray[np.float64]
    target_truth: NDArray[np.float64]


def moved_sessions(cell: SyntheticCell, seed: int = 0, move_sigmas: float = 3.0,
                   fraction: float = 0.3, noise_axis: Optional[float] = None) -> SessionCell:
    """``cell``'s single measurements as session ``s1``; a share ``fraction`` of the fiducials
    and every target measured again (new noise) as session ``s2``, after the working frame moved
    by ``move_sigmas`` x the noise per axis along each axis and by a rotation of that size at
    the cell's RMS radius. ``move_sigmas`` 0: the same sessions without a move.

    The targets of the session cell are measured in both sessions; ``s2`` (the latest) is where
    the targets are used.
    """
    rng = np.random.default_rng([seed, 35])
    d = cell.spec.dimension
    sigma = cell.spec.sigma / math.sqrt(d) if noise_axis is None else noise_axis
    first = np.array([m[0] for m in cell.fiducial_measurements])
    tfirst = np.array([m[0] for m in cell.target_measurements])
    bias_f = cell.fiducial_biased
    centre = first.mean(axis=0)
    radius = float(np.sqrt(np.mean(np.sum((first - centre) ** 2, axis=1))))
    shift = move_sigmas * sigma * rng.choice([-1.0, 1.0], size=d)
    angle = move_sigmas * sigma / radius
    if d == 2:
        c, s = math.cos(angle), math.sin(angle)
        r = np.array([[c, -s], [s, c]])
    else:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        r = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k

    def move(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return (p - centre) @ r.T + centre + shift

    again = np.sort(rng.choice(len(first), size=max(d + 1, round(fraction * len(first))),
                               replace=False))
    new_f = move(bias_f[again] + rng.normal(0, sigma, size=(len(again), d)))
    tbias = cell.target_biased
    new_t = move(tbias + rng.normal(0, sigma, size=tbias.shape))
    ids = cell.fiducial_ids + tuple(cell.fiducial_ids[k] for k in again)
    sessions = ("s1",) * len(first) + ("s2",) * len(again)
    working = np.vstack([first, new_f])
    destination = np.vstack([cell.fiducial_truth, cell.fiducial_truth[again]])
    tids = cell.target_ids + cell.target_ids
    tses = ("s1",) * len(tfirst) + ("s2",) * len(tfirst)
    return SessionCell(ids, sessions, working, destination, tids, tses,
                       np.vstack([tfirst, new_t]), cell.target_truth)
