"""``~/markers`` of ``registration_node``: the fiducials and their corrections for RViz, built
from an immutable :class:`~rbc_registration.pipeline.state.ModelState`. Units: metres (REP 103).
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Duration, Time
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..pipeline.settings import Settings
from ..pipeline.state import ModelState
from .conversions import array_to_point, embed_3d


def _color(r: float, g: float, b: float, a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=a)


def markers_msg(state: ModelState, settings: Settings, now: Time) -> MarkerArray:
    """``~/markers`` in the destination frame: enabled fiducials (green spheres), disabled ones
    (grey), and per enabled fiducial an arrow along its correction mapped by R_c, drawn
    ``marker_arrow_gain`` times longer than the correction. Starts with DELETEALL."""
    out = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
    fiducials, model = state.fiducials, state.model
    if fiducials is None:
        return out
    frame, ns, scale = settings.destination_frame, "rbc_registration", settings.marker_scale

    def marker(kind: int, mid: int, name: str) -> Marker:
        m = Marker(type=kind, id=mid, ns=f"{ns}/{name}", action=Marker.ADD)
        m.header.frame_id = frame
        m.header.stamp = now
        m.pose.orientation.w = 1.0
        m.lifetime = Duration()
        return m

    def xyz(points: np.ndarray) -> np.ndarray:
        return points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])

    spheres = marker(Marker.SPHERE_LIST, 0, "fiducials")
    spheres.scale.x = spheres.scale.y = spheres.scale.z = scale
    spheres.color = _color(0.1, 0.8, 0.2)
    spheres.points = [array_to_point(p) for p in xyz(fiducials.destination)]
    out.markers.append(spheres)
    if fiducials.disabled_ids:
        disabled = marker(Marker.TEXT_VIEW_FACING, 1, "disabled")
        disabled.scale.z = scale
        disabled.color = _color(0.6, 0.6, 0.6)
        disabled.text = "disabled: " + ", ".join(fiducials.disabled_ids)
        out.markers.append(disabled)
    if model is None:
        return out
    r, t = embed_3d(model.corrected.rotation, model.corrected.translation)
    start = xyz(fiducials.destination)
    step = xyz(np.asarray(model.corrections)) @ r.T * (-settings.marker_arrow_gain)
    for k in range(len(start)):
        arrow = marker(Marker.ARROW, k, "corrections")
        arrow.scale.x, arrow.scale.y, arrow.scale.z = scale * 0.2, scale * 0.4, scale * 0.4
        arrow.color = _color(0.9, 0.3, 0.1)
        arrow.points = [array_to_point(start[k]), array_to_point(start[k] + step[k])]
        out.markers.append(arrow)
    return out
