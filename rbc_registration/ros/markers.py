"""``~/markers`` of ``registration_node``: the fiducials and their corrections for RViz, built
from an immutable :class:`~rbc_registration.pipeline.state.ModelState`. Units: metres (REP 103).

Built by the recompute thread, never on the executor: the sphere lists hold every fiducial
(one marker each), the arrows and labels are at most ``max_markers``.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Duration, Time
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..pipeline.settings import Settings
from ..pipeline.state import ModelState
from . import fast_msgs
from .conversions import embed_3d

NS = "rbc_registration"


def _color(r: float, g: float, b: float, a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=a)


def _xyz(points: np.ndarray) -> np.ndarray:
    """(J, 2|3) -> (J, 3), z = 0 in 2D."""
    points = np.asarray(points, dtype=np.float64)
    if points.size == 0:                # no fiducials (e.g. the first rebuild after ~/reset)
        return np.empty((0, 3))
    points = points.reshape(len(points), -1)
    return points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])


def _points(xyz: np.ndarray) -> list:
    return [fast_msgs.point(*p) for p in _xyz(xyz).tolist()]


def largest(norms: np.ndarray, count: int) -> np.ndarray:
    """Indices of the ``count`` largest of ``norms``, in index order (all when fewer)."""
    if count >= len(norms):
        return np.arange(len(norms))
    if count <= 0:
        return np.arange(0)
    return np.sort(np.argpartition(-norms, count - 1)[:count])


def markers_msg(state: ModelState, settings: Settings, now: Time,
                disabled_points: Mapping[str, Sequence[float]] = {}) -> MarkerArray:
    """``~/markers`` in the destination frame: DELETEALL, the enabled fiducials (green sphere
    list), the disabled ones (grey sphere list, each labelled ``disabled: <id>`` at its mean
    destination point), and from each enabled fiducial's destination point an arrow along the
    shift its correction applies (the corrected point is x - eps: -R_c eps in the destination
    frame), drawn ``marker_arrow_gain`` times longer than the correction. Labels and arrows
    together are at most ``max_markers``: labels first, then the arrows of the largest
    corrections.

    :param disabled_points: mean destination point (2 or 3 coordinates) of each disabled
        fiducial, by id (:meth:`~rbc_registration.pipeline.ingest.Ingest.disabled_points`).
    """
    out = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
    fiducials, model = state.fiducials, state.model
    if fiducials is None:
        return out
    frame, scale = settings.destination_frame, settings.marker_scale
    budget = settings.max_markers

    def marker(kind: int, mid: int, name: str) -> Marker:
        m = Marker(type=kind, id=mid, ns=f"{NS}/{name}", action=Marker.ADD)
        m.header.frame_id = frame
        m.header.stamp = now
        m.pose.orientation.w = 1.0
        m.lifetime = Duration()
        return m

    spheres = marker(Marker.SPHERE_LIST, 0, "fiducials")
    spheres.scale.x = spheres.scale.y = spheres.scale.z = scale
    spheres.color = _color(0.1, 0.8, 0.2)
    spheres.points = _points(fiducials.destination)
    out.markers.append(spheres)
    disabled = [(fid, disabled_points[fid]) for fid in fiducials.disabled_ids
                if fid in disabled_points]
    if disabled:
        grey = marker(Marker.SPHERE_LIST, 0, "disabled_fiducials")
        grey.scale.x = grey.scale.y = grey.scale.z = scale
        grey.color = _color(0.6, 0.6, 0.6)
        at = _xyz(np.array([p for _, p in disabled]))
        grey.points = _points(at)
        out.markers.append(grey)
        for k, ((fid, _), (x, y, z)) in enumerate(zip(disabled[:budget], at.tolist())):
            label = marker(Marker.TEXT_VIEW_FACING, k, "disabled")
            label.pose.position = fast_msgs.point(x, y, z + scale)  # just above its sphere
            label.scale.z = scale
            label.color = _color(0.6, 0.6, 0.6)
            label.text = f"disabled: {fid}"
            out.markers.append(label)
        budget -= min(budget, len(disabled))
    if model is None:
        return out
    r, t = embed_3d(model.corrected.rotation, model.corrected.translation)
    start = _xyz(fiducials.destination)
    step = _xyz(np.asarray(model.corrections)) @ r.T * (-settings.marker_arrow_gain)
    chosen = largest(np.linalg.norm(step, axis=1), budget)
    starts, ends = start[chosen].tolist(), (start[chosen] + step[chosen]).tolist()
    arrow = marker(Marker.ARROW, 0, "corrections")
    arrow.scale.x, arrow.scale.y, arrow.scale.z = scale * 0.2, scale * 0.4, scale * 0.4
    arrow.color = _color(0.9, 0.3, 0.1)
    # the arrows share every field but id and points (1,000 generated Markers took 50-100 ms of
    # Python on the recompute thread, which slowed the executor's answers meanwhile)
    point = fast_msgs.point
    out.markers.extend(fast_msgs.like(arrow, id=k, points=[point(*a), point(*b)])
                       for k, a, b in zip(chosen.tolist(), starts, ends))
    return out
