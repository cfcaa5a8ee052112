"""The /diagnostics level rules (pipeline.health) on a fake clock (pure)."""

import pytest

from rbc_registration.pipeline.health import HealthInputs, HealthMonitor, Level

GOOD = HealthInputs(model_valid=True, model_error="", confident=True,
                    decision_reason="Kriging corrections predicted ...", n_fiducials=48,
                    method="kriging", n_rejected=0, n_pending=0)


def test_ok_for_a_valid_model_with_a_confident_decision_applied_or_not():
    monitor = HealthMonitor(10.0)
    assert monitor.assess(GOOD, 0.0).level is Level.OK
    plain = GOOD._replace(method="uncorrected", decision_reason="No correction beat ...")
    h = monitor.assess(plain, 1.0)
    assert h.level is Level.OK and h.message == "48 fiducials, decision uncorrected: No " \
                                                "correction beat ..."


def test_error_without_a_model_and_for_the_journal():
    monitor = HealthMonitor(10.0)
    h = monitor.assess(GOOD._replace(model_valid=False, model_error="3 enabled fiducials"), 0.0)
    assert h == (Level.ERROR, "no model: 3 enabled fiducials")
    h = monitor.assess(GOOD._replace(journal_error="disk full"), 1.0)
    assert h == (Level.ERROR, "journal: disk full")


def test_warn_publish_only_calibration():
    h = HealthMonitor(10.0).assess(GOOD._replace(model_valid=False, calibration="calibration "
                                                 "from a.yaml"), 0.0)
    assert h == (Level.WARN, "publish-only: calibration from a.yaml")


def test_warn_uncertain_decision():
    h = HealthMonitor(10.0).assess(GOOD._replace(confident=False, decision_reason="rho 1.8"), 0.0)
    assert h == (Level.WARN, "uncertain decision: rho 1.8")


def test_warn_for_a_suspect_fiducial_after_an_uncertain_decision():
    line = "fiducial H17: held-out error 0.0027 m, 90 x the median ..."
    h = HealthMonitor(10.0).assess(GOOD._replace(model_warning=line), 0.0)
    assert h == (Level.WARN, line)
    h = HealthMonitor(10.0).assess(GOOD._replace(model_warning=line, confident=False,
                                                 decision_reason="rho 1.8"), 0.0)
    assert h == (Level.WARN, f"uncertain decision: rho 1.8; {line}")


def test_a_clock_warning_is_a_warn_with_a_valid_model_and_said_with_no_model():
    line = "use_sim_time is true and no /clock message has arrived: ..."
    assert HealthMonitor(10.0).assess(GOOD._replace(clock_warning=line), 0.0) == (Level.WARN, line)
    h = HealthMonitor(10.0).assess(GOOD._replace(clock_warning=line, model_valid=False,
                                                 model_error="2 fiducials"), 0.0)
    assert h == (Level.ERROR, f"no model: 2 fiducials; {line}")


def test_warn_for_rejections_since_the_previous_report_only():
    monitor = HealthMonitor(10.0)
    assert monitor.assess(GOOD._replace(n_rejected=2), 0.0) == (
        Level.WARN, "2 measurement(s) rejected since the last report")
    assert monitor.assess(GOOD._replace(n_rejected=2), 1.0).level is Level.OK
    assert "1 measurement(s) rejected" in monitor.assess(GOOD._replace(n_rejected=3), 2.0).message


def test_warn_for_a_stale_model_on_the_clock():
    monitor = HealthMonitor(5.0)
    pending = GOOD._replace(n_pending=4)
    assert monitor.assess(pending, 100.0).level is Level.OK     # pending since now
    assert monitor.assess(pending, 104.9).level is Level.OK
    h = monitor.assess(pending, 106.0)
    assert h == (Level.WARN, "stale model: 4 measurement(s) waiting for 6 s (stale_after 5 s)")
    assert monitor.assess(GOOD, 107.0).level is Level.OK        # rebuilt: the clock restarts
    assert monitor.assess(pending, 108.0).level is Level.OK


def test_several_reasons_are_all_named():
    monitor = HealthMonitor(1.0)
    monitor.assess(GOOD._replace(n_pending=1), 0.0)
    h = monitor.assess(GOOD._replace(confident=False, decision_reason="r", n_rejected=1,
                                     n_pending=1), 2.0)
    assert h.level is Level.WARN
    assert h.message == ("uncertain decision: r; 1 measurement(s) rejected since the last "
                         "report; stale model: 1 measurement(s) waiting for 2 s (stale_after "
                         "1 s)")


def test_stale_after_must_be_positive():
    with pytest.raises(ValueError, match="stale_after must be > 0 s, got 0"):
        HealthMonitor(0)
