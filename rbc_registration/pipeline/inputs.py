"""Recorded inputs of the node, as read from a bag (:mod:`rbc_registration.io.bag.reader`) and
fed through the pipeline offline (:mod:`.offline`). Plain records, no numpy, no rclpy.
Units: metres, stamps in seconds, ``log_ns`` the receive time in nanoseconds.
"""

from __future__ import annotations

from typing import NamedTuple, Optional


class PairMessage(NamedTuple):
    """A ``FiducialPair`` (``fiducial_id`` may be empty: id assigned by proximity);
    ``stamp_ns``: the header stamp in whole nanoseconds when known (a bag's), else ``None``;
    ``stamp_error``: why the header stamp is not a time (then ``stamp_s`` is NaN), else empty;
    ``group`` and ``session`` as in the message (empty: its own group, the current session)."""

    log_ns: int
    stamp_s: float
    fiducial_id: str
    working: tuple[float, float, float]
    working_frame: str
    destination: tuple[float, float, float]
    destination_frame: str
    stamp_ns: Optional[int] = None
    stamp_error: str = ""
    group: str = ""
    session: str = ""


class PointMessage(NamedTuple):
    """A ``PointStamped`` of stream ``"working"`` or ``"destination"``
    (:data:`~rbc_registration.core.constants.WORKING`, ``DESTINATION``); ``stamp_error`` as
    in :class:`PairMessage`."""

    log_ns: int
    stream: str
    xyz: tuple[float, float, float]
    frame_id: str
    stamp_s: float
    stamp_error: str = ""

