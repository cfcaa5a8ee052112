"""The parts of a :class:`~rbc_registration.ros.node.RegistrationNode` that its mixins share,
declared once with their types. :meth:`~rbc_registration.ros.node.RegistrationNode._start`
sets every one of them; a mixin (services, publishing, parameters, planning) derives from
:class:`NodeParts` and uses only these.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Callable, Optional

if TYPE_CHECKING:    # the types only: no import cycle with the mixins' modules
    from geometry_msgs.msg import TransformStamped
    from rclpy.publisher import Publisher

    from ..pipeline.health import HealthMonitor
    from ..pipeline.ingest import Ingest
    from ..pipeline.settings import Settings
    from ..pipeline.state import ModelState
    from ..pipeline.worker import LatestWriter, RecomputeWorker
    from .samples import SampleTaker
    from .saved import Loaded
    from .tf_static import StaticTf


class NodeParts:
    """What the node's mixins share (set in ``RegistrationNode._start``)."""

    #: The validated parameters (pipeline.settings); replaced on an accepted change.
    _settings: Settings
    #: The served model state; replaced whole by the recompute thread (no lock to read it).
    _state: ModelState
    #: Pairing, validation, journaling and counting of the inputs.
    _ingest: Ingest
    #: The debounced rebuild thread.
    _worker: RecomputeWorker
    #: The /diagnostics levels.
    _health: HealthMonitor
    #: The snapshot (and checkpoint) writer thread, of ``(state, generation)``.
    _snapshots: LatestWriter
    #: A calibration file loaded at start (``calibration_file``), or None.
    _loaded: Optional[Loaded]
    #: ``~/take_sample``'s sources.
    _samples: SampleTaker
    #: /tf_static (None of tf2_ros's: ``_tf.available`` says whether it is published).
    _tf: StaticTf
    #: The transforms /tf_static chooses from, by ``tf_broadcast``; {} = none.
    _tf_transforms: dict[str, TransformStamped]
    _pub_transform: Publisher
    _pub_transform_u: Publisher
    _pub_status: Publisher
    _pub_markers: Publisher
    _pub_diagnostics: Publisher
    #: Serialises what is published about a model (transforms, /tf_static, markers).
    _pub_lock: threading.Lock
    #: ``~/reset`` against the snapshot thread.
    _snapshot_lock: threading.Lock
    #: Bumped by ``~/reset``: a rebuild or snapshot of an older generation is dropped.
    _generation: int
    #: How a snapshot file is written (path, text); injectable for tests.
    _write_snapshot: Callable[[str, str], None]

    def _publish_tf(self) -> None:
        """Publish /tf_static from :attr:`_tf_transforms` (:class:`PublishingMixin`)."""
        raise NotImplementedError

    def _publish_status(self) -> None:
        """Publish ``~/status`` and /diagnostics (:class:`PublishingMixin`)."""
        raise NotImplementedError

    def _measurements_changed(self) -> None:
        """Ask for a rebuild after the measurements changed (the node)."""
        raise NotImplementedError

    def _plan_model(self, state: ModelState) -> None:
        """Compute the planner's error model of ``state`` (:class:`PlanningMixin`)."""
        raise NotImplementedError

    def _expected_target_error(self) -> float:
        """The served model's expected target error [m] (:class:`PlanningMixin`)."""
        raise NotImplementedError
