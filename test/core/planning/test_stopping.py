"""The planner's stopping rules and their one-sentence verdict (core/planning/stopping.py)."""

import pytest
from hypothesis import given, settings, strategies as st

from rbc_registration.core.planning.stopping import ENOUGH_RULES, rules_holding, verdict


def test_the_within_rule_is_now_within_f_of_the_error_with_every_candidate():
    assert rules_holding(1.10, 0.5, 1.0, 0.10, 0.0, 0.0) == ["within"]
    assert rules_holding(1.1001, 0.5, 1.0, 0.10, 0.0, 0.0) == []
    assert rules_holding(1.5, 0.5, 1.0, 0.0, 0.0, 0.0) == []          # within 0: off
    assert rules_holding(1.0, 0.5, None, 0.10, 0.0, 0.0) == []        # with_all not computed


def test_the_gain_rule_is_a_fraction_or_a_length():
    assert rules_holding(1.0, 0.019, 0.1, 0.10, 0.02, 0.0) == ["gain"]
    assert rules_holding(1.0, 0.021, 0.1, 0.10, 0.02, 0.0) == []
    assert rules_holding(1.0, 0.04, 0.1, 0.10, 0.02, 0.05) == ["gain"]  # the larger threshold
    assert rules_holding(1.0, 0.0, 0.1, 0.0, 0.0, 0.0) == []            # both off: never
    assert rules_holding(1.05, 0.001, 1.0, 0.10, 0.02, 0.0) == list(ENOUGH_RULES)


def test_enough_names_its_rule_and_the_numbers():
    v = verdict(1.05, 1.0, 40, "candidate #3", 0.2, [0.9], [0.2], 0.10, 0.0, 0.0, [])
    assert v.enough and v.rule == "within" and v.enough_after == 0
    assert v.reason == ("enough: the expected median target error 1.05 is 5.0 % above the 1 "
                        "expected with all 40 candidates measured, within 10 %")
    g = verdict(2.0, 1.0, 40, "group 'pose7'", 0.01, [1.99], [0.01], 0.10, 0.02, 0.0, [])
    assert g.enough and g.rule == "gain"
    assert g.reason == ("enough: the best next group 'pose7' is expected to reduce it by 0.50 % "
                        "(0.01), less than 2 %")
    both = verdict(1.05, 1.0, 40, "candidate #3", 0.001, [1.049], [0.001], 0.10, 0.02, 0.01, [])
    assert both.rule == "within+gain" and "; and the best next" in both.reason
    assert "less than 2 % or 0.01" in both.reason


def test_measure_more_says_when_a_rule_is_expected_to_hold():
    after = [1.6, 1.3, 1.08, 1.05]
    v = verdict(2.0, 1.0, 40, "candidate #0", 0.4, after, [0.4, 0.3, 0.22, 0.03], 0.10, 0.0,
                0.0, [])
    assert not v.enough and v.rule is None and v.enough_after == 3      # 1.08 <= 1.1 at step 3
    assert v.reason == ("measure more: the expected median target error 2 is 100.0 % above the 1 "
                        "expected with all 40 candidates measured, more than 10 %; the best next "
                        "candidate #0 is expected to reduce it by 20.00 % (0.4); after the first "
                        "3 suggestion(s) a rule is expected to hold")
    none = verdict(2.0, 1.0, 40, "candidate #0", 0.4, after[:2], [0.4, 0.3], 0.10, 0.0, 0.0, [])
    assert none.enough_after is None and "expected to hold" not in none.reason
    # the gain rule at a step uses the next step's gain
    g = verdict(2.0, None, 40, "candidate #0", 0.4, [1.9, 1.89], [0.4, 0.1, 0.01], 0.10, 0.02,
                0.0, [])
    assert g.enough_after == 2
    assert "the error with every candidate measured is not computed" in g.reason
    assert "at least 2 %" in g.reason


def test_held_back_says_why_and_what_to_measure_and_nothing_else():
    v = verdict(1.0, 1.0, 40, "candidate #0", 0.0, [1.0], [0.0], 0.10, 0.02, 0.0,
                ["the error model is not yet trustworthy (12 held-out fiducials)"],
                "measure at least 3 more fiducials")
    assert not v.enough and v.rule is None and v.enough_after is None
    assert v.reason == ("measure more: the error model is not yet trustworthy (12 held-out "
                        "fiducials); measure at least 3 more fiducials; the stopping rules apply "
                        "once it is")


@settings(max_examples=200, deadline=None)
@given(st.floats(0.01, 10), st.floats(0.01, 10), st.floats(0, 1), st.floats(0, 2),
       st.floats(0, 0.5), st.floats(0, 0.5))
def test_the_verdict_never_contradicts_itself(now, with_all, frac, within, fraction, length):
    gain = frac * now
    after = [now - gain, now - 1.5 * gain]
    v = verdict(now, with_all, 10, "candidate #1", gain, after, [gain, 0.5 * gain], within,
                fraction, length, [])
    assert v.reason.startswith("enough: " if v.enough else "measure more: ")
    assert ("measure more" in v.reason) != v.enough and ("enough:" in v.reason) == v.enough
    assert v.enough == bool(rules_holding(now, gain, with_all, within, fraction, length))
    if v.enough:
        assert v.enough_after == 0 and set(v.rule.split("+")) <= set(ENOUGH_RULES)
    elif v.enough_after is not None:
        assert 1 <= v.enough_after <= len(after)
        assert "expected to hold" in v.reason


@pytest.mark.parametrize("within", [0.10, 0.5])
def test_within_is_said_as_a_percentage(within):
    v = verdict(1.0, 1.0, 5, "candidate #0", 0.0, [1.0], [0.0], within, 0.0, 0.0, [])
    assert f"within {100 * within:g} %" in v.reason
