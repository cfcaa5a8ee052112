"""``/diagnostics`` from a status message (message types only, no rclpy.init)."""

import pytest

pytest.importorskip("rbc_registration_interfaces.msg")

from builtin_interfaces.msg import Time  # noqa: E402
from rbc_registration_interfaces.msg import RegistrationStatus  # noqa: E402

from rbc_registration.pipeline.health import Health, Level  # noqa: E402
from rbc_registration.ros.status import DIAGNOSTIC_LEVEL, diagnostics_msg  # noqa: E402

#: Every rejection counter of RegistrationStatus (its fields, so a new reason is covered too).
COUNTERS = tuple(f for f in RegistrationStatus.get_fields_and_field_types()
                 if f.startswith("n_rejected_"))


def test_every_rejection_counter_is_a_diagnostics_key_with_its_value():
    """A bridged topic (every pair twice) shows as ``WARN … rejected``; the keys say why."""
    assert {"n_rejected_duplicate", "n_rejected_conflict"} <= set(COUNTERS)
    status = RegistrationStatus(working_frame_id="tracker", destination_frame_id="world")
    for k, field in enumerate(COUNTERS):
        setattr(status, field, 11 + k)
    status.n_rejected = sum(11 + k for k in range(len(COUNTERS)))
    msg = diagnostics_msg(status, "/cell_a/registration_node", Time(sec=5),
                          Health(Level.WARN, "measurements rejected"))
    (d,) = msg.status
    values = {kv.key: kv.value for kv in d.values}
    assert {f: values[f] for f in COUNTERS} == {f: str(11 + k) for k, f in enumerate(COUNTERS)}
    assert values["n_rejected"] == str(status.n_rejected)
    assert (d.level, d.message) == (DIAGNOSTIC_LEVEL[Level.WARN], "measurements rejected")
    assert (d.name, d.hardware_id) == ("/cell_a/registration_node: registration",
                                     "tracker->world")
    assert msg.header.stamp.sec == 5
