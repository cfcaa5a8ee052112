"""Callback boundaries of registration_node (pure: no rclpy)."""

from rbc_registration.ros.guards import guard_input, guard_service


def test_guards_answer_and_log_unexpected_errors():
    class Log:
        def __init__(self):
            self.lines = []

        def error(self, line):
            self.lines.append(line)

    class Response:
        success, message = True, ""

    log = Log()

    def broken(*_):
        raise RuntimeError("bug")

    response = guard_service(log, "~/correct_target", broken)(None, Response())
    assert not response.success and response.message == "internal error: bug"
    guard_input(log, "~/fiducial_pairs", broken)(object())
    assert log.lines == ["~/correct_target failed: RuntimeError: bug",
                         "~/fiducial_pairs: message dropped: RuntimeError: bug"]
