"""registration_node's measurement planner in process: ``~/suggest_next`` against the core
planner on the served model, bad requests answered success=false with the reason, and
``~/status`` ``expected_target_error`` (NaN without a model, set once a model is built)."""

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from geometry_msgs.msg import Point  # noqa: E402

from rbc_registration.core.planning.model_planner import expected_target_error, plan_from_model  # noqa: E402,E501
from rbc_registration.core.planning.planner import PlanConfig  # noqa: E402
from rbc_registration.pipeline.planning import TARGET_REPEATS, planning_state  # noqa: E402

#: The node plans for targets measured once (pipeline/planning.py).
NODE = PlanConfig(target_repeats=TARGET_REPEATS)
from rbc_registration_interfaces.msg import RegistrationStatus  # noqa: E402
from rbc_registration_interfaces.srv import SuggestNext  # noqa: E402
from ros_helpers import wait_for  # noqa: E402
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros


def points(xyz):
    return [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in xyz]


class TestSuggestNext(NodeTestBase):

    @classmethod
    def setup_class(cls):
        super().setup_class()
        fid = cls.cell["fid"]
        # the grid's holes x = 0, 0.3 (first half) measured; every hole a candidate
        cls.left = [k for k in range(cls.n) if fid[k] < 24]
        cls.holes = np.array([cls.cell["working"][fid == h].mean(axis=0)
                              for h in range(len(cls.cell["ids"]))])

    def planned_node(self, **params):
        node = self.make_node(**params)
        self.stream(node, self.left)
        state = self.recompute(node)
        wait_for(lambda: not math.isnan(node.status().expected_target_error),
                 what="the planner's expected error")
        return node, state

    def suggest(self, node, candidates, targets=(), count=1):
        return self.srv(node, SuggestNext, "suggest_next", SuggestNext.Request(
            candidates=points(candidates), targets=points(targets), count=count))

    def test_ranking_prefers_the_empty_half_and_matches_the_core(self):
        node, state = self.planned_node()
        r = self.suggest(node, self.holes, count=4)
        assert r.success, r.message
        assert len(r.ranked) == 4 and len(set(r.ranked)) == 4
        assert all(k >= 24 for k in r.ranked[:2])     # holes of the unmeasured half first
        p = plan_from_model(state.model, self.holes, count=4, config=NODE)
        assert list(r.ranked) == list(p.sequence)
        np.testing.assert_allclose(r.expected_error_after, p.expected_after, rtol=1e-9)
        assert r.expected_error_now == pytest.approx(p.expected_now, rel=1e-9)
        assert (r.enough, r.reason) == (p.enough, p.reason) and not r.enough
        assert r.model_trusted == p.model_check.trustworthy and r.enough_rule == ""
        assert r.expected_error_with_all == pytest.approx(p.expected_with_all, rel=1e-9)
        assert list(r.ranked_groups) == []
        assert r.expected_error_after[0] < r.expected_error_now
        assert "4 suggestion(s) of 48 candidates from 24 fiducials" in r.message
        # targets given: the error is taken there
        targets = self.cell["targets"]
        r = self.suggest(node, self.holes, targets, count=0)      # count 0: one
        p = plan_from_model(state.model, self.holes, targets, config=NODE)
        assert r.success and list(r.ranked) == list(p.sequence) and p.on_targets
        assert r.expected_error_now == pytest.approx(p.expected_now, rel=1e-9)

    def test_stopping_rule_follows_the_parameters(self):
        node, state = self.planned_node(plan_min_gain_fraction=0.9, plan_within=0.0)
        r = self.suggest(node, self.holes)
        p = plan_from_model(state.model, self.holes,
                            config=PlanConfig(within=0.0, min_gain_fraction=0.9,
                                              target_repeats=TARGET_REPEATS))
        assert r.success and r.reason == p.reason and r.enough == p.enough
        assert r.model_trusted == p.model_check.trustworthy
        if r.model_trusted:
            assert r.enough and r.enough_rule == "gain" and r.reason.startswith("enough:")
        else:                   # never enough while the error model check fails
            assert not r.enough and "the stopping rules apply once it is" in r.reason

    def test_grouped_candidates_are_ranked_as_a_whole(self):
        node, state = self.planned_node()
        labels = [f"pose{k // 3}" for k in range(len(self.holes))]     # 16 poses of 3 holes
        r = self.srv(node, SuggestNext, "suggest_next", SuggestNext.Request(
            candidates=points(self.holes), count=2, candidate_groups=labels))
        assert r.success, r.message
        p = plan_from_model(state.model, self.holes, count=2, config=NODE, groups=labels)
        assert list(r.ranked_groups) == [p.unit_labels[u] for u in p.sequence]
        assert len(r.ranked_groups) == 2 and len(r.ranked) == 6
        assert list(r.ranked) == list(p.ranked_candidates)
        assert all(labels[k] == r.ranked_groups[i // 3] for i, k in enumerate(r.ranked))
        np.testing.assert_allclose(r.expected_error_after, p.expected_after, rtol=1e-9)
        assert "2 suggestion(s) of 16 candidate groups" in r.message
        bad = self.srv(node, SuggestNext, "suggest_next", SuggestNext.Request(
            candidates=points(self.holes), count=1, candidate_groups=labels[:5]))
        assert not bad.success and bad.message.startswith("candidate_groups: 5 labels for 48 "
                                                          "candidates")

    def test_status_has_the_expected_target_error_after_a_model(self):
        node = self.make_node()
        assert math.isnan(node.status().expected_target_error) and not node.status().model_valid
        r = self.suggest(node, self.holes)
        assert not r.success and r.message.startswith("no model yet")
        node, state = self.planned_node()
        status = node.status()
        # the served error calibrated by the cross-validated held-out errors (planning thread)
        assert status.expected_target_error == pytest.approx(
            planning_state(state).expected_target_error, rel=1e-9)
        ratio = planning_state(state).check.ratio
        assert status.expected_target_error == pytest.approx(
            ratio * expected_target_error(state.model, config=NODE), rel=1e-9)
        assert 0 < status.expected_target_error < 1e-3    # metres: a sub-millimetre error
        published = self.latest(node, RegistrationStatus, f"/{node.get_name()}/status",
                                predicate=lambda m: not math.isnan(m.expected_target_error))
        assert published.expected_target_error == status.expected_target_error
        # every hole measured: a new model, and the status follows it (its own work volume)
        self.stream(node, [k for k in range(self.n) if k not in self.left])
        new = self.recompute(node)
        wait_for(lambda: node.status().n_fiducials == 48
                 and not math.isnan(node.status().expected_target_error),
                 what="the planner on the new model")
        assert node.status().expected_target_error == pytest.approx(
            planning_state(new).expected_target_error, rel=1e-9)
        assert new.model is not state.model

    def test_bad_requests_get_a_reason_and_the_node_keeps_serving(self):
        node, _ = self.planned_node(max_candidates=10)
        few = self.holes[20:30]
        cases = [
            (self.holes[:11], (), 1, "11 candidates in one request, more than max_candidates "
                                     "(10)"),
            (few, self.holes[:11], 1, "11 targets in one request, more than max_candidates"),
            ((), (), 1, "no candidates"),
            (few[:3], (), 5, "count (5) exceeds the number of candidates (3)"),
            (few, (), 11, "count 11: at most 10 suggestions per request"),
            (few, (), 2 ** 32 - 1, "count 4294967295: at most 10 suggestions per request"),
            (np.vstack([few[:3], [[0.1, float("nan"), 0.2]]]), (), 1,
             "candidates contains NaN or inf (first at row 3"),
            (few, [[float("inf"), 0, 0]], 1, "targets contains NaN or inf"),
        ]
        for candidates, targets, count, message in cases:
            r = self.suggest(node, candidates, targets, count)
            assert not r.success and message in r.message, (message, r.message)
            assert list(r.ranked) == [] and list(r.expected_error_after) == []
        assert self.suggest(node, few, count=3).success


class TestSuggestNext2D(NodeTestBase):

    def test_2d_ignores_z(self):
        node = self.make_node(dimension=2)
        self.stream(node)
        state = self.recompute(node)
        wait_for(lambda: not math.isnan(node.status().expected_target_error),
                 what="the planner's expected error")
        cand = np.array([[0.1, 0.2, 5.0], [0.5, -0.3, float("nan")], [0.7, 0.1, -3.0]])
        r = self.srv(node, SuggestNext, "suggest_next", SuggestNext.Request(
            candidates=points(cand), count=2))
        assert r.success, r.message
        p = plan_from_model(state.model, cand[:, :2], count=2, config=NODE)
        assert list(r.ranked) == list(p.sequence)
