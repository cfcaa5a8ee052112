"""Set-up errors the numbers show: a likely unit mismatch between fiducials and targets (say
fiducials in mm, targets in m: every target outside the fiducials' hull and the targets' scale off
by a large factor), and between the two frames of the fiducials (:func:`frame_mismatch`: one
frame in another unit, or mirrored)."""

from __future__ import annotations

import math
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..validation import rounding

#: Every target outside the hull, and the targets' distance from the fiducials' centre (or
#: their spread) this many times the fiducials' size (or this many times smaller): a likely
#: unit mismatch (m vs mm is 1000, m vs cm 100).
UNIT_MISMATCH_FACTOR = 100.0
#: The fiducials' size (RMS distance from their centroid) in one frame this many times that in
#: the other: a unit mismatch between the frames (in / cm is 2.54; real instruments' scale errors
#: are below 1e-3, which the correction handles as bias).
FRAME_SCALE_FACTOR = 2.0
#: A reflection fitting the fiducials with an RMS residual this many times smaller than the best
#: rotation: the destination frame is a mirror image of the working frame (a flat cell, which a
#: reflection through its plane fits as well as a rotation, gives about 1).
MIRROR_FACTOR = 10.0


def _rms_radius(points: np.ndarray, centre: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))


def unit_mismatch(fiducials: ArrayLike, targets: ArrayLike, inside_hull: Optional[ArrayLike],
                  what: str = "targets", noun: str = "targets") -> Optional[str]:
    """The warning for targets that look like they are in another unit than the fiducials.

    :param fiducials: fiducial locations (J, d), working frame.
    :param targets: target locations (K, d), working frame.
    :param inside_hull: (K,) the interpolation's inside-hull flags; ``None``: no hull (the
        destination frame's target truth), the distances alone decide.
    :param what: what the points are, for the message (e.g. ``target truth``).
    :param noun: what one calls them when counting (``targets``, ``candidates``).
    :return: one line naming the likely mismatch and the factor, or ``None``.
    """
    f = np.asarray(fiducials, dtype=float)
    t = np.asarray(targets, dtype=float)
    if len(t) == 0 or len(f) == 0 or (inside_hull is not None
                                      and np.any(np.asarray(inside_hull, dtype=bool))):
        return None
    centre = f.mean(axis=0)
    size = _rms_radius(f, centre)
    if not size > 0:
        return None
    # the median distance: one mistyped target does not make a unit mismatch of all of them
    far = float(np.median(np.linalg.norm(t - centre, axis=1))) / size
    spread = _rms_radius(t, t.mean(axis=0)) / size if len(t) >= 2 else 0.0
    # Points in a larger unit shrink towards the frame's origin with their spread: a tight
    # cluster of holes (one fixture, one hole sent twice) at the cell is no unit mismatch.
    origin = np.zeros_like(centre)
    shrunk = _rms_radius(t, origin) * UNIT_MISMATCH_FACTOR <= _rms_radius(f, origin)
    if far >= UNIT_MISMATCH_FACTOR:
        ratio, how = far, "farther from the fiducials' centre than the fiducials' size (median)"
    elif 0 < spread <= 1 / UNIT_MISMATCH_FACTOR and shrunk:
        ratio, how = 1 / spread, ("smaller in spread (and nearer the frame's origin) than the "
                                  "fiducials")
    else:
        return None
    where = "outside the fiducials' hull and " if inside_hull is not None else ""
    return (f"all {len(t)} {noun} are {where}~{ratio:.3g}x {how}: likely a unit mismatch "
            f"between {what} and fiducials (e.g. m vs mm)")


def point_sets_unit_mismatch(fiducials: ArrayLike, hull: Any,
                             named: Sequence[tuple[str, Optional[ArrayLike]]]) -> list[str]:
    """:func:`unit_mismatch` of each named set of points (e.g. ``("candidates", c)``, ``None``:
    not given), inside-hull flags from ``hull`` (an :class:`~.interpolation.HullTest` of the
    fiducials): the warning lines, one per set that looks like another unit."""
    out = []
    for what, points in named:
        if points is not None:
            pts = np.asarray(points, dtype=float)
            text = unit_mismatch(fiducials, pts, hull.simplices(pts) >= 0, what, what)
            if text:
                out.append(text)
    return out


def frame_mismatch(working: ArrayLike, destination: ArrayLike) -> Optional[str]:
    """Why the two frames of the fiducials cannot be related by a rigid motion, when it is plain.

    :param working: fiducials in the working frame (J, d), validated.
    :param destination: the same fiducials in the destination frame (J, d).
    :return: one line (the frames' sizes differ by :data:`FRAME_SCALE_FACTOR` or more: a unit
        mismatch; or a reflection fits :data:`MIRROR_FACTOR` times better than any rotation: a
        mirrored frame), else ``None``.
    """
    x = np.asarray(working, dtype=float)
    y = np.asarray(destination, dtype=float)
    if len(x) < 2:                       # nothing to compare: the count check says so
        return None
    xc, yc = x - x.mean(axis=0), y - y.mean(axis=0)
    sx, sy = _rms_radius(xc, 0.0), _rms_radius(yc, 0.0)
    if not (sx > 0 and sy > 0):
        return None                      # coincident points: the registration says so
    ratio = sy / sx
    if not 1 / FRAME_SCALE_FACTOR < ratio < FRAME_SCALE_FACTOR:
        return (f"the destination fiducials are {ratio:.4g}x the size of the working fiducials "
                f"(RMS distance from their centroid {sy:.6g} against {sx:.6g}): likely the "
                "frames are in different units (e.g. m vs mm); a rigid registration needs one")
    u, sv, vt = np.linalg.svd(xc.T @ yc)
    if np.linalg.det(u @ vt) >= 0:
        return None
    flip = np.ones(len(sv))
    flip[-1] = -1.0
    mirrored = _rms_radius(xc @ (u @ vt) - yc, 0.0)           # the best orthogonal map
    rotated = _rms_radius(xc @ (u * flip @ vt) - yc, 0.0)     # the best rotation
    if rotated <= MIRROR_FACTOR * mirrored + 1e-12 * max(sx, sy):
        return None
    return (f"the destination frame looks mirrored against the working frame: a reflection fits "
            f"the fiducials with RMS residual {mirrored:.3g}, the best rotation only "
            f"{rotated:.3g}; check the handedness of the frames' axes")


#: Fiducials farther than this from their centroid (RMS, metres) are unlikely in a cell recorded
#: in metres (REP 103): a bag in millimetres reads 1000x too large.
LARGEST_CELL_M = 100.0


#: Fiducials closer than this to their centroid (RMS, metres) are unlikely in a cell: a file in
#: metres read as millimetres is 1000x too small.
SMALLEST_CELL_M = 1e-3


def implausible_size(points: ArrayLike, metres_per_unit: float, unit: str) -> Optional[str]:
    """The warning for fiducials in a file whose size in its stated ``unit`` looks like another
    unit (a CSV in millimetres read as metres, or the reverse), or ``None``.

    :param points: fiducials (J, d) in ``unit``; :param metres_per_unit: the unit in metres.
    :return: one line naming the size, when it is above :data:`LARGEST_CELL_M` or below
        :data:`SMALLEST_CELL_M` in metres.
    """
    p = np.asarray(points, dtype=float)
    size = _rms_radius(p, p.mean(axis=0)) if len(p) else 0.0
    metres = size * metres_per_unit
    if metres > LARGEST_CELL_M:
        how = f"larger than any cell ({LARGEST_CELL_M:g} m): a file in smaller units"
    elif 0 < metres < SMALLEST_CELL_M:
        how = f"smaller than any cell ({SMALLEST_CELL_M:g} m): a file in larger units"
    else:
        return None
    in_metres = f" ({metres:.4g} m)" if metres_per_unit != 1.0 else ""
    return (f"the fiducials' RMS distance from their centroid is {size:.4g} {unit}{in_metres}, "
            f"{how} (e.g. mm read as m, or m as mm)? check --unit; an exported calibration "
            f"converts by it")


def implausible_metres(points: ArrayLike) -> Optional[str]:
    """The warning for fiducials (metres) whose size looks like millimetres, or ``None``.

    :param points: fiducials (J, d) in metres (a bag's, the node's).
    :return: one line naming the size, or ``None`` below :data:`LARGEST_CELL_M`.
    """
    p = np.asarray(points, dtype=float)
    size = _rms_radius(p, p.mean(axis=0)) if len(p) else 0.0
    if not size > LARGEST_CELL_M:
        return None
    return (f"the fiducials' RMS distance from their centroid is {size:.4g} m: ROS data are in "
            f"metres (REP 103); a recording in millimetres reads 1000x too large (and "
            f"outlier_distance, merge_radius are metres)")


#: Read in 2D, the fiducials are named as distorted when the frames' relative tilt (the 3D
#: rigid fit's rotation) changes their xy distances by at least this fraction of the mismatch as
#: read (sigma_L0, eq. 7, of the xy points) ...
TILT_SHARE = 0.25
#: ... by at least this fraction of the cell's xy RMS radius (10 ppm: below the length accuracy
#: of large-volume instruments; exact synthetic points would otherwise be named for any tilt) ...
TILT_RELATIVE = 1e-5
#: ... and by at least this many times what the fit's own uncertainty would make of it (its
#: rotation is off by about FRE / the fiducials' RMS radius, which turns points at different
#: heights: in a volume, or with a frame whose z is no measurement, that alone is of the order
#: of the mismatch).
TILT_SIGNIFICANCE = 3.0
#: ... and only when the xy points show it: their sigma_L0 at least this fraction of the spread
#: the tilt would give the xy mismatch (the same xy in both frames with another z: no tilt).
TILT_SEEN = 0.5
#: Fiducials the check looks at, at most (evenly spaced in their order): O(J^2) pairs.
TILT_MAX_POINTS = 2000


def dropped_z_warning(working: ArrayLike, destination: ArrayLike, unit: str) -> Optional[str]:
    """The warning for fiducials read in 2D whose frames' xy planes are not parallel (a plate
    tilted in one of them), so that the xy distances are foreshortened in one frame and not in
    the other, or ``None``.

    The rotation R of the 3D rigid fit (eq. 2) turns the working points to the destination's
    orientation; their xy distances before and after R differ by what the frames' relative tilt
    does to them (nothing when R turns about z only: a constant z offset, the same tilt in both
    frames), heights and steps included. That, RMS over the pairs, is named when it is at least
    :data:`TILT_SHARE` of sigma_L0 of the xy points as read, :data:`TILT_RELATIVE` of the cell,
    and :data:`TILT_SIGNIFICANCE` times what the fit's uncertainty alone would make of it
    (R off by FRE / RMS radius, times the pairs' height differences), and when the xy points show
    it (:data:`TILT_SEEN`). The corrections take such a distortion as bias (a smooth field), so
    the corrected registration hardly suffers; the uncorrected one does (the RA-like plate tilted
    3 degrees: TRE_u 0.44 instead of 0.32 mm).

    Limits: with a frame whose z is no measurement (a drawing's 0, no z column), a tilt of a
    flat plate is named, but fiducials at different heights (steps, a boss) make the 3D fit's
    misfit too large to tell a tilt from them, and nothing is said.

    :param working: (J, 3) the fiducials in the working frame (rows with a NaN: not given,
        ignored); :param destination: (J, 3) the same in the destination frame; :param unit: of
        the lengths, for the text ("": none named).
    """
    from scipy.spatial.distance import pdist

    from .registration import rigid_fit

    w, d = np.asarray(working, dtype=float), np.asarray(destination, dtype=float)
    keep = np.isfinite(w).all(axis=1) & np.isfinite(d).all(axis=1)
    w, d = w[keep], d[keep]
    if len(w) > TILT_MAX_POINTS:
        pick = np.linspace(0, len(w) - 1, TILT_MAX_POINTS).round().astype(np.intp)
        w, d = w[pick], d[pick]
    if len(w) < 3:
        return None
    try:
        fit = rigid_fit(w, d)
    except ValueError:                              # collinear or coincident: no tilt to tell
        return None
    turned = w @ fit.rotation.T                     # the working points, destination-oriented
    flat = pdist(w[:, :2])
    change = flat - pdist(turned[:, :2])
    tilt = float(np.sqrt(np.mean(change ** 2)))
    radius = _rms_radius(w, w.mean(axis=0))
    heights = float(np.sqrt(np.mean(pdist(turned[:, 2:]) ** 2)))
    noise = fit.fre_rms / radius * heights if radius > 0 else math.inf
    sigma_l0 = float(np.std(flat - pdist(d[:, :2])))                 # eq. 1, 7 in 2D
    size = _rms_radius(d[:, :2], d[:, :2].mean(axis=0))
    if not (tilt >= TILT_SHARE * sigma_l0 and tilt >= TILT_RELATIVE * size
            and tilt >= TILT_SIGNIFICANCE * noise and tilt > 0
            and sigma_l0 >= TILT_SEEN * float(np.std(change))):
        return None
    degrees = math.degrees(math.acos(min(1.0, abs(float(fit.rotation[2, 2])))))
    u = f" {unit}" if unit else ""
    return (f"read in 2D, the frames' xy planes are {degrees:.2g} degrees apart (the 3D fit's "
            f"rotation; a plate tilted in one of them?): the tilt changes the fiducials' xy "
            f"distances by {tilt:.3g}{u} RMS, against a mismatch sigma_L0 of {sigma_l0:.3g}{u}; "
            f"the corrections take it as bias, the uncorrected registration does not. Level the "
            f"plate, or read the fiducials in 3D with the kriging interpolation (the paper's 3D "
            f"interpolation needs fiducials off a plane)")


#: The uncorrected FRE above this fraction of the destination fiducials' RMS radius: the frames
#: do not match rigidly (one axis in another unit, a scaled frame). Bias and noise of a real cell
#: are far below it (the synthetic cells: at most ~0.1 %).
NONRIGID_FRACTION = 0.02
#: The corrected registration's FRE above this fraction of the uncorrected one after an
#: iterative restoration: the Gauss-Newton steps did not restore the rigid-body condition (the
#: corrected fiducials' FRE is ~1e-6 of it and less when they did).
UNCONVERGED_FRACTION = 0.01
#: ... and above this many times the coordinates' rounding (:func:`~.validation.rounding`).
UNCONVERGED_ROUNDING = 1e3


def rigidity_warnings(model: Any, unit: str) -> list[str]:
    """The warnings of a built model whose frames do not match rigidly, or whose iterative
    restoration did not converge (:data:`NONRIGID_FRACTION`, :data:`UNCONVERGED_FRACTION`).

    :param model: an :class:`~.model.RbcModel`; :param unit: its lengths' unit, for the text.
    """
    out = []
    fre_u, fre_c = model.uncorrected.fre_rms, model.corrected.fre_rms
    dest = np.asarray(model.destination, dtype=float)
    size = _rms_radius(dest, dest.mean(axis=0)) if len(dest) else 0.0
    if size > 0 and fre_u > NONRIGID_FRACTION * size:
        out.append(f"the frames do not match rigidly: the uncorrected FRE {fre_u:.4g} {unit} is "
                   f"{100 * fre_u / size:.3g} % of the fiducials' RMS distance from their "
                   f"centroid ({size:.4g} {unit}; a cell's bias and noise are well below 1 %): "
                   f"one axis in another unit, or a scaled frame? check each axis of both "
                   f"frames")
    config = model.config
    # exact data: both FREs are rounding, whatever their ratio
    floor = UNCONVERGED_ROUNDING * rounding(model.working, model.destination)
    if (config.restoration == "iterative" and fre_c > UNCONVERGED_FRACTION * fre_u
            and fre_c > floor):
        out.append(f"the restoration did not converge in {config.steps} step(s): the corrected "
                   f"fiducials' FRE is {fre_c:.4g} {unit}, {100 * fre_c / fre_u:.3g} % of the "
                   f"uncorrected {fre_u:.4g} {unit} (about 0 once the rigid-body condition is "
                   f"restored; sigma_L does not show it on nearly coplanar or collinear "
                   f"fiducials, whose distances barely change off their plane or line): use more "
                   f"steps, the closed-form restoration, or dimension 2 for a plate")
    return out
