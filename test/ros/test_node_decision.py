"""registration_node in process: the decision in ~/status, /diagnostics levels for each
condition, ~/get_fiducials (a planted outlier stands out), the removed apply_corrections."""

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402
from rbc_registration_interfaces.srv import GetFiducials, SetFiducialEnabled  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from ros_helpers import expected_state, make_cell, pair_msg, wait_for  # noqa: E402
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros


class TestDecisionInStatusAndDiagnostics(NodeTestBase):

    def diagnostics(self, node, predicate=lambda s: True, got=None):  # also TestGetFiducials
        """The newest /diagnostics status of ``node`` satisfying ``predicate``: among ``got``
        (messages an earlier :meth:`watch` collects and keeps collecting), else from a new
        subscription."""
        name = f"{node.get_fully_qualified_name()}: "
        own = got is None
        if own:
            got, sub = TestDecisionInStatusAndDiagnostics.watch(self)

        def mine():
            return [s for m in got for s in m.status if s.name.startswith(name) and predicate(s)]
        try:
            wait_for(lambda: mine(), what="a /diagnostics status")
            return mine()[-1]
        finally:
            if own:
                self.ros.client.destroy_subscription(sub)

    def watch(self):
        """A /diagnostics subscription collecting into a list: (the list, the subscription)."""
        got = []
        return got, self.ros.client.create_subscription(DiagnosticArray, "/diagnostics",
                                                        got.append, 10)

    @staticmethod
    def values(status):
        return {kv.key: kv.value for kv in status.values}

    def test_error_without_a_model_then_ok_with_a_confident_decision(self):
        node = self.make_node()
        d = self.diagnostics(node)
        assert d.level == DiagnosticStatus.ERROR and d.message.startswith("no model: ")
        self.stream(node)
        state = self.recompute(node)
        decision = state.model.decision
        assert decision.confident and decision.apply
        d = self.diagnostics(node, lambda s: s.level != DiagnosticStatus.ERROR)
        assert d.level == DiagnosticStatus.OK, d.message
        assert d.message == f"48 fiducials, decision {decision.method}: {decision.reason}"
        v = self.values(d)
        assert (v["decision"], v["method"]) == ("cv", decision.method)
        assert float(v["sigma_axis [m]"]) == pytest.approx(state.model.sigma_axis, rel=1e-9)
        assert float(v["rho"]) == pytest.approx(state.model.rho, rel=1e-9)
        assert "sigma [m]" in v and "expected_tre_median [m]" in v

    def test_ok_when_a_confident_decision_does_not_apply_corrections(self):
        node = self.make_node(decision="off")
        self.stream(node)
        self.recompute(node)
        d = self.diagnostics(node, lambda s: s.level != DiagnosticStatus.ERROR)
        assert d.level == DiagnosticStatus.OK and "decision uncorrected" in d.message
        assert not node.status().corrections_applied

    def test_warn_for_an_uncertain_decision(self):
        sigma_l0 = expected_state(self.cell).model.sigma_l[0]
        node = self.make_node(decision="rho", sigma=sigma_l0 / 1.7)   # rho between 1 and 2.5
        self.stream(node)
        state = self.recompute(node)
        assert state.model.recommendation == "uncertain" and not state.model.decision.confident
        d = self.diagnostics(node, lambda s: s.level != DiagnosticStatus.ERROR)
        assert d.level == DiagnosticStatus.WARN
        assert d.message.startswith("uncertain decision: The paper's rule: rho = ")
        assert not node.status().decision_confident

    def test_warn_for_rejections_since_the_last_report(self):
        node = self.make_node()
        self.stream(node)
        self.recompute(node)
        # subscribed (and matched: a report arrived) before the rejection, whose WARN is in one
        # report only
        got, sub = self.watch()
        try:
            self.diagnostics(node, got=got)
            pub = self.publisher(node, FiducialPair, "fiducial_pairs")
            pub.publish(pair_msg(self.cell, 0, frame="elsewhere"))
            wait_for(lambda: node.status().n_rejected == 1, what="rejection")
            d = self.diagnostics(node, lambda s: "rejected" in s.message, got=got)
            assert d.level == DiagnosticStatus.WARN
            assert "1 measurement(s) rejected since the last report" in d.message
            # The next reports see no new rejection: OK again.
            got.clear()
            d = self.diagnostics(node, lambda s: s.level == DiagnosticStatus.OK, got=got)
            assert "rejected" not in d.message
        finally:
            self.ros.client.destroy_subscription(sub)

    def test_warn_for_a_stale_model(self):
        node = self.make_node(stale_after=0.05)
        self.stream(node)
        self.recompute(node)
        assert node.set_parameters([Parameter("debounce_period", value=60.0)])[0].successful
        self.stream(node, range(3), stamp_offset=1000.0)   # accepted, not rebuilt for minutes
        d = self.diagnostics(node, lambda s: "stale model" in s.message)
        assert d.level == DiagnosticStatus.WARN
        assert "3 measurement(s) waiting for" in d.message and "stale_after 0.05 s" in d.message


class TestGetFiducials(NodeTestBase):

    @classmethod
    def setup_class(cls):
        super().setup_class()
        cls.cell = make_cell(seed=4, bias=2e-4)
        cls.outlier = 17
        working = cls.cell["working"].copy()
        working[cls.cell["fid"] == cls.outlier] += [2e-3, -1.5e-3, 1e-3]   # a misread hole
        cls.cell = {**cls.cell, "working": working}
        cls.n = len(cls.cell["fid"])

    def test_a_planted_outlier_has_the_largest_residuals(self):
        node = self.make_node()
        empty = self.srv(node, GetFiducials, "get_fiducials")
        assert not empty.success and empty.message.startswith("no model yet")
        assert not empty.fiducials
        self.stream(node)
        state = self.recompute(node)
        r = self.srv(node, GetFiducials, "get_fiducials")
        assert r.success and r.method == state.model.decision.method
        ids = [f.fiducial_id for f in r.fiducials]
        assert ids == list(self.cell["ids"])
        planted = self.cell["ids"][self.outlier]
        for field in ("correction_norm", "cv_error", "cv_error_uncorrected",
                      "residual_uncorrected"):
            values = [getattr(f, field) for f in r.fiducials]
            assert ids[int(np.argmax(values))] == planted, field
        model = expected_state(self.cell).model
        k = list(model.ids).index(planted)
        f = r.fiducials[ids.index(planted)]
        assert f.enabled and f.n_measurements == 3
        assert f.correction_norm == pytest.approx(np.linalg.norm(model.corrections[k]), rel=1e-9)
        assert f.cv_error_uncorrected == pytest.approx(
            model.decision.cross_validation.errors["uncorrected"][k], rel=1e-9)
        np.testing.assert_allclose([f.working_mean.x, f.working_mean.y, f.working_mean.z],
                                   model.working[k], rtol=1e-12)
        np.testing.assert_allclose(
            [f.destination_mean.x, f.destination_mean.y, f.destination_mean.z],
            model.destination[k], rtol=1e-12)
        # Disabled: still listed, model values NaN.
        assert self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                        SetFiducialEnabled.Request(fiducial_id=planted, enabled=False)).success
        self.recompute(node)
        r = self.srv(node, GetFiducials, "get_fiducials")
        f = [f for f in r.fiducials if f.fiducial_id == planted][0]
        assert not f.enabled and f.n_measurements == 3 and len(r.fiducials) == 48
        assert all(math.isnan(getattr(f, n)) for n in ("correction_norm", "cv_error",
                                                        "cv_error_uncorrected",
                                                        "residual_uncorrected"))

    def test_the_planted_outlier_is_named_in_status_and_diagnostics_until_disabled(self):
        """As register and evaluate do (core/decision/evaluation.py ``blunders``): a fiducial whose
        held-out error stands out is a WARN naming it; disabled, the node is OK again."""
        node = self.make_node()
        self.stream(node)
        state = self.recompute(node)
        planted = self.cell["ids"][self.outlier]
        assert state.warning.startswith(f"fiducial {planted}: held-out error ")
        assert " m, " in state.warning and "check its points first" in state.warning
        assert node.status().message == state.warning
        d = TestDecisionInStatusAndDiagnostics.diagnostics(
            self, node, lambda s: s.level != DiagnosticStatus.ERROR)
        assert d.level == DiagnosticStatus.WARN and d.message.startswith(state.warning)
        assert self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                        SetFiducialEnabled.Request(fiducial_id=planted, enabled=False)).success
        state = self.recompute(node)
        assert state.warning == "" and node.status().message == ""
        d = TestDecisionInStatusAndDiagnostics.diagnostics(
            self, node, lambda s: s.level == DiagnosticStatus.OK)
        assert planted not in d.message


class TestSimTimeWithoutClock(NodeTestBase):

    def test_use_sim_time_without_clock_is_a_warn_until_clock_arrives(self):
        """use_sim_time with no /clock: every stamp is 0 and the age checks compare against
        time 0; /diagnostics says so (a WARN with a valid model: test_health) and still beats
        (its timer is on steady time); the first /clock clears it."""
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        from rbc_registration.ros.status import NO_CLOCK
        node = self.make_node(use_sim_time=True, status_period=0.1)
        d = TestDecisionInStatusAndDiagnostics.diagnostics(self, node,
                                                           lambda s: NO_CLOCK in s.message)
        assert d.level == DiagnosticStatus.ERROR and d.message.startswith("no model: ")
        assert node.status().header.stamp.sec == 0      # the heartbeat runs on steady time
        pub = self.ros.client.create_publisher(Clock, "/clock", 10)
        try:
            def ticked():
                pub.publish(Clock(clock=Time(sec=1000)))
                return node.status().header.stamp.sec >= 1000
            wait_for(ticked, what="the node's /clock")
            d = TestDecisionInStatusAndDiagnostics.diagnostics(
                self, node, lambda s: NO_CLOCK not in s.message)
            assert "/clock" not in d.message
        finally:
            self.ros.client.destroy_publisher(pub)


class TestRemovedParameter(NodeTestBase):

    def test_apply_corrections_at_start_names_its_replacement(self):
        with pytest.raises(ValueError, match="parameter apply_corrections no longer exists: it "
                                             "was replaced by 'decision'"):
            RegistrationNode("reg_removed", context=self.ros.context,
                             parameter_overrides=[Parameter("apply_corrections", value="on"),
                                                  Parameter("state_dir", value="")])


class TestWarmStart(NodeTestBase):

    def test_the_served_hyperparameters_start_the_next_fit_when_enabled(self):
        from rbc_registration.pipeline.state import build_state

        seen = []

        def recording_build(fiducials, settings, stamp_ns, previous=None):
            seen.append(previous)
            return build_state(fiducials, settings, stamp_ns, previous)

        node = self.make_node(kriging_warm_start=True, node_options={"build": recording_build})
        self.stream(node)
        first = self.recompute(node).model.kriging_hyperparameters
        assert first is not None   # cv cross-validates kriging: it is always fitted
        self.recompute(node)
        assert seen[-1] == first
        assert node.set_parameters([Parameter("kriging_warm_start", value=False)])[0].successful
        self.recompute(node)
        assert seen[-1] is None


def tilted_plate(degrees: float, seed: int = 0) -> dict:
    """A 7 x 7 plate of holes 0.1 m apart in the world's xy plane; the tracker sees it turned
    0.4 rad about z, shifted, and tilted ``degrees`` about x, with 20 µm noise per axis."""
    rng = np.random.default_rng(seed)
    truth = np.array([[x, y, 0.0] for x in range(7) for y in range(7)]) * 0.1
    a, b = 0.4, np.radians(degrees)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    fid = np.arange(len(truth))
    working = (truth - [0.3, 0.3, 0.0]) @ (rx @ rz).T + [1.0, 0.2, 0.5]
    working += rng.normal(0.0, 2e-5, working.shape)
    return {"ids": np.array([f"P{k:02d}" for k in fid]), "fid": fid, "working": working,
            "destination": truth.copy(), "targets": working[:4]}


class TestDroppedZ(NodeTestBase):
    """the tilted-plate warning of `register` and `evaluate` (core/scale.
    dropped_z_warning) was not given by the node with dimension 2. It is the model state's
    warning now (the ingestion keeps each fiducial's first 3D points): in ~/status's message
    and /diagnostics WARN; a level plate has none."""

    def test_a_tilted_plate_read_in_2d_is_named_in_the_status(self):
        for degrees, named in ((3.0, True), (0.0, False)):
            self.cell = tilted_plate(degrees)
            self.n = len(self.cell["fid"])
            node = self.make_node(dimension=2)
            self.stream(node)
            state = self.recompute(node)
            assert state.model is not None
            assert ("read in 2D, the frames' xy planes are 3 degrees apart"
                    in state.warning) == named, state.warning
            if named:
                assert "m RMS, against a mismatch sigma_L0 of" in state.warning
                wait_for(lambda n=node: "read in 2D" in n.status().message,
                         what="status message")
