"""The node is built on rclpy's public API: no method of ours overrides a private member of
rclpy's ``Node`` (such an override can break with the next rclpy release)."""

import ast
from pathlib import Path

from rclpy.node import Node

ROS = Path(__file__).resolve().parents[2] / "rbc_registration" / "ros"


def _methods() -> list[tuple[str, str]]:
    out = []
    for path in sorted(ROS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                out += [(f"{path.name}:{item.lineno} {node.name}.{item.name}", item.name)
                        for item in node.body if isinstance(item, ast.FunctionDef)]
    return out


def test_no_private_rclpy_node_member_is_overridden():
    private = {name for name in dir(Node) if name.startswith("_") and not name.startswith("__")}
    methods = _methods()
    assert len(methods) > 50       # the scan sees the node's classes
    overridden = [where for where, name in methods if name in private]
    assert overridden == [], f"private rclpy Node members overridden: {overridden}"


def test_the_parameter_callbacks_are_registered_through_the_public_api():
    text = (ROS / "param_callbacks.py").read_text()
    for public in ("add_pre_set_parameters_callback", "add_on_set_parameters_callback",
                   "add_post_set_parameters_callback"):
        assert f"self.{public}(" in text
