"""The settings as ROS parameters of registration_node: declare, the reason for a wrong ROS
type, and the API reference (pure: no rclpy)."""

import os
import re

from rbc_registration.pipeline.settings import SPECS
from rbc_registration.ros import params


def test_params_module_does_not_need_rclpy_to_validate():
    assert "declare" in dir(params)  # declare imports rcl_interfaces lazily, only when called


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_api_reference_documents_every_parameter_topic_and_service():
    with open(os.path.join(ROOT, "msg_docs", "README.md")) as f:
        doc = f.read()
    with open(os.path.join(ROOT, "rbc_registration", "ros", "node.py")) as f:
        node_source = f.read()
    names = set(re.findall(r'"(~/[a-z_]+|/diagnostics)"', node_source))
    assert len(names) >= 13
    for name in sorted(names) + [f"`{p}`" for p in SPECS]:
        assert name in doc, f"{name} is not documented in msg_docs/README.md"


def test_a_wrong_type_names_the_parameter_and_both_types():
    assert params.type_error("sigma", "INTEGER", 1) == (
        "Wrong parameter type: sigma must be of type double, got integer 1 (write 1.0)")
    assert params.type_error("interpolation", "BOOL", True) == (
        "Wrong parameter type: interpolation must be of type string, got bool True (YAML reads "
        "an unquoted on, off, yes, no, true or false as a boolean: quote it, e.g. "
        "interpolation:=\"'off'\" on the command line or interpolation: 'off' in a file)")


def test_a_wrong_type_of_a_parameter_rclpy_declares_names_its_declared_type():
    """use_sim_time:=1 was refused as "must be of type ?"."""
    assert params.type_error("use_sim_time", "INTEGER", 1, "BOOL") == (
        "Wrong parameter type: use_sim_time must be of type bool, got integer 1")
    assert params.type_error("use_sim_time", "STRING", "yes", "BOOL") == (
        "Wrong parameter type: use_sim_time must be of type bool, got string 'yes' (write "
        "use_sim_time:=true or use_sim_time:=false, unquoted)")
    assert params.type_error("x", "DOUBLE_ARRAY", [1.0], "NOT_SET") == (
        "Wrong parameter type: x does not take this type, got double array [1.0]")
    # the node's own parameters keep their SPECS type whatever the descriptor says
    assert params.type_error("sigma", "INTEGER", 1, "NOT_SET").startswith(
        "Wrong parameter type: sigma must be of type double, got integer 1")


def test_start_up_overrides_the_node_does_not_have_are_named_with_the_closest_parameter():
    """-p decison:="'off'" started the node with the decision cv, without a word."""
    assert params.unknown_overrides(["decision", "use_sim_time", "qos_overrides./tf.depth"]) == ""
    text = params.unknown_overrides(["decison", "interpolaton", "sigma", "colour"])
    assert text == ("ignored 3 parameter(s) this node does not have: colour, decison (did you "
                    "mean decision?), interpolaton (did you mean interpolation?) (its "
                    "parameters: msg_docs/README.md)")
