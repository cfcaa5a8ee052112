"""Every example command of README.md and docs/*.md runs here, so the docs and the code cannot
drift apart.

The commands are the lines of each document's ```` ```bash ```` blocks (a trailing ``\\`` joins
the next line, ``#`` starts a comment). Each document is one session, in a temporary directory
holding a copy of ``examples/``, with its own ``ROS_HOME`` (so the nodes' default ``state_dir``),
and the commands run in document order:

- ``rbc-registration ...`` and ``python examples/...``: for real, through bash (pipes too); the
  exit status must be 0 and stderr must hold no error line.
- ``source scripts/env.sh``: it must put ``.venv/bin``'s ``rbc-registration`` on ``PATH``.
- ``registration_node --ros-args ...``, ``ros2 run PKG EXE ...`` (the venv's
  ``lib/PKG/EXE``, where ``ros2 run`` looks) and ``ros2 launch rbc_registration FILE args``
  (the launch file's own plain-Python rules, the node started with the parameters they give):
  the node runs in the background until the next one starts or the document ends.
- ``ros2 topic pub`` and ``ros2 service call``: performed with rclpy against that node (ros2cli
  is not installed): the YAML is set field by field into the message type named, a fiducial pair
  must be accepted (``~/status``), a service must answer ``success``, and a corrected target of
  an examples TARGETS.csv must be within its 95 % bound of the file's truth.

A command the test does not know is a failure; the few that cannot run here (a workspace build,
the test suite itself) are listed in :data:`NOT_RUN`, each with its reason, by its exact text.
"""

from __future__ import annotations

import csv
import importlib
import importlib.util
import math
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys
import time
from typing import Any, Optional

import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test" / "ros"))
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BIN = pathlib.Path(sys.executable).parent
COMMAND_TIMEOUT_S = 300.0
NODE_START_TIMEOUT_S = 60.0

#: Commands of the docs that are not run here, by their exact text, each with its reason.
NOT_RUN = {
    "bash scripts/demo.sh": "the demo; test/ros/test_replay.py runs it",
    "bash scripts/test.sh": "the test suite itself",
    "scripts/bootstrap.sh": "builds the venv these tests run in",
    "scripts/test.sh [pytest args]": "the test suite itself",
    "source scripts/env.sh": None,   # performed: see Session.do_env
    "export ROS_DOMAIN_ID=7": "the test process's own ROS domain (test/conftest.py) stands in",
    # docs/BUILD.md: a colcon workspace and a pip venv of one's own, outside this checkout.
    "mkdir -p ~/rbc_ws/src && cd ~/rbc_ws/src": "a colcon workspace outside the checkout",
    "git clone <this repository> rbc_registration": "a colcon workspace outside the checkout",
    "ln -s rbc_registration/msg_docs/rbc_registration_interfaces rbc_registration_interfaces":
        "a colcon workspace outside the checkout",
    "cd ~/rbc_ws": "a colcon workspace outside the checkout",
    "source /opt/ros/kilted/setup.bash": "a system ROS 2 install",
    "rosdep install --from-paths src --ignore-src -y": "system packages (root)",
    "colcon build": "a colcon workspace outside the checkout",
    "source install/setup.bash": "a colcon workspace outside the checkout",
    "ros2 run rbc_registration registration_node --ros-args --params-file my_params.yaml":
        "a parameter file of one's own",
    "ros2 launch rbc_registration publish.launch.py calibration:=line1":
        "a calibration named line1 saved by one's own cell",
    "ros2 launch rbc_registration publish.launch.py calibration:=/path/cell_a.yaml":
        "a placeholder path",
    "ros2 service call /cell_a/registration_node/save std_srvs/srv/Trigger":
        "the cell_a node of one's own workspace",
    "ros2 launch rbc_registration registration.launch.py namespace:=cell_a "
    "calibration_file:=/path/cell_a.yaml": "a placeholder path",
    "rbc-registration export ~/.ros/rbc_registration/cell_a.registration_node/calibration.json "
    "--out cell_a.yaml": "the snapshot of one's own cell_a node",
    "ros2 service call /cell_a/registration_node/take_sample "
    "rbc_registration_interfaces/srv/TakeSample \"{fiducial_id: H07}\"":
        "a tracker and a robot streaming points",
    "mkdir -p ~/rbc_ws/src && cd ~/rbc_ws/src && git clone <this repository> rbc_registration "
    "&& cd ..": "a pip venv of one's own, outside the checkout",
    "python3.11 -m venv ~/rbc_ws/venv && source ~/rbc_ws/venv/bin/activate":
        "a pip venv of one's own, outside the checkout",
    "pip install colcon-common-extensions -r src/rbc_registration/requirements.txt "
    "-c src/rbc_registration/constraints.txt": "a pip venv of one's own (network)",
    'bash src/rbc_registration/scripts/patch_wheel_cmake.sh "$VIRTUAL_ENV"':
        "a pip venv of one's own",
    'export AMENT_PREFIX_PATH="$VIRTUAL_ENV"': "a pip venv of one's own",
    "colcon build --base-paths src src/rbc_registration/msg_docs "
    "src/rbc_registration/vendor/tf2_msgs --cmake-args -DBUILD_TESTING=OFF":
        "a colcon workspace outside the checkout",
    "export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST": "set for every test by test/conftest.py",
    "install/rbc_registration/lib/rbc_registration/registration_node":
        "a colcon workspace outside the checkout",
    "python3 -m venv ~/rbc_offline && source ~/rbc_offline/bin/activate":
        "a venv of one's own; test/cli/test_no_ros.py runs the offline commands without ROS",
    "pip install numpy scipy matplotlib rosbags pyyaml": "a venv of one's own (network)",
    "pip install --no-deps .": "a venv of one's own",
    "rbc-registration evaluate my_cell_bag --out report/": "a bag of one's own cell",
    'PY="$(bash scripts/compat_venv.sh | tail -n 1)"':
        "builds the Ubuntu 24.04 venv; CI runs it (.ci/run)",
    'cd /tmp && "$PY" -m pytest <repo>/test --ignore=<repo>/test/ros -q':
        "the test suite itself, in the Ubuntu 24.04 venv",
}
#: docs/HARDENING.md's commands run parts of the test suite: not run from a test.
SUITE = re.compile(r"^bash scripts/test\.sh( test/\S+)+( -q)?( -s)?$")


# --- reading the commands --------------------------------------------------------------------

def _strip_comment(line: str) -> str:
    """``line`` without a ``#`` comment (one outside quotes, at a word's start)."""
    quote = None
    for k, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1].isspace()):
            return line[:k].rstrip()
    return line.rstrip()


def doc_commands(path: pathlib.Path) -> list[tuple[int, str]]:
    """``(line number, command)`` of every command in the ```bash blocks of ``path``."""
    commands: list[tuple[int, str]] = []
    in_bash = False
    pending, start = "", 0
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.startswith("```"):
            in_bash = line.strip() == "```bash" and not in_bash
            continue
        if not in_bash:
            continue
        text = _strip_comment(line)
        if not pending:
            start = number
        if text.endswith("\\"):
            pending += text[:-1].strip() + " "
            continue
        command = (pending + text.strip()).strip()
        pending = ""
        if command:
            commands.append((start, command))
    return commands


def _words(command: str) -> list[str]:
    return shlex.split(command)


def kind(command: str) -> str:
    """How the test performs ``command``: a runner's name, or ``not run``; ``unknown``."""
    if command in NOT_RUN and NOT_RUN[command] is not None:
        return "not run"
    if SUITE.match(command):
        return "not run"
    if command == "source scripts/env.sh":
        return "env"
    words = _words(command)
    if words[0] == "rbc-registration" or words[:2] == ["python", "examples/node_client.py"] \
            or (words[0] == "python" and words[1:2] and words[1].startswith("examples/")):
        return "shell"
    if words[0] == "registration_node":
        return "node"
    if words[:2] == ["ros2", "run"] and len(words) >= 4:
        return "node" if words[3] == "registration_node" else "ros2 run"
    if words[:2] == ["ros2", "launch"] and len(words) >= 4 and words[2] == "rbc_registration":
        return "launch"
    if words[:3] == ["ros2", "topic", "pub"]:
        return "topic pub"
    if words[:3] == ["ros2", "service", "call"]:
        return "service call"
    return "unknown"


def test_every_command_of_the_docs_is_known():
    unknown = [f"{path.relative_to(ROOT)}:{number}: {command}"
               for path in DOCS for number, command in doc_commands(path)
               if kind(command) == "unknown"]
    assert not unknown, "commands the test does not know:\n" + "\n".join(unknown)


def test_the_not_run_list_holds_only_commands_of_the_docs():
    every = {command for path in DOCS for _, command in doc_commands(path)}
    stale = sorted(set(NOT_RUN) - every)
    assert not stale, f"NOT_RUN names commands no document has: {stale}"


def test_the_readme_shows_the_whole_path_of_a_new_cell():
    kinds = [kind(command) for _, command in doc_commands(ROOT / "README.md")]
    commands = " ".join(command for _, command in doc_commands(ROOT / "README.md"))
    for needed in ("rbc-registration register", "rbc-registration plan",
                   "rbc-registration export", "registration_node --ros-args",
                   "calibration_file:=", "examples/node_client.py", "/correct_target",
                   "/save"):
        assert needed in commands, needed
    assert {"topic pub", "service call", "node", "shell"} <= set(kinds)
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 200


# --- performing them -------------------------------------------------------------------------

def _example_targets() -> list[tuple[str, list[float], list[float]]]:
    """``(file, working, truth)`` of every examples TARGETS.csv row with truth, in metres."""
    rows = []
    for path in sorted((ROOT / "examples").glob("*/targets.csv")):
        with open(path, newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                axes = [a for a in "xyz" if f"w{a}" in row]
                rows.append((str(path.relative_to(ROOT)),
                             [float(row[f"w{a}"]) * 1e-3 for a in axes],
                             [float(row[f"d{a}"]) * 1e-3 for a in axes]))
    return rows


def _message_type(name: str) -> Any:
    """``pkg/msg/Name`` or ``pkg/srv/Name`` -> the Python class."""
    package, kind_, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind_}"), type_name)


def fill(message: Any, values: Any, where: str = "") -> Any:
    """Set ``values`` (a mapping, as ``ros2 topic pub`` reads its YAML) into ``message``."""
    if values is None:
        return message
    assert isinstance(values, dict), f"{where or 'message'}: expected a mapping, got {values!r}"
    fields = message.get_fields_and_field_types()
    for key, value in values.items():
        assert key in fields, f"{type(message).__name__} has no field {where}{key}"
        current = getattr(message, key)
        if isinstance(value, dict):
            fill(current, value, f"{where}{key}.")
        elif isinstance(current, float):
            setattr(message, key, float(value))
        else:
            setattr(message, key, value)
    return message


def _node_name(words: list[str]) -> str:
    """The fully qualified name of a node started with ``words`` (``-r __ns:=``/``__node:=``)."""
    ns, name = "", "registration_node"
    for k, word in enumerate(words[:-1]):
        if word in ("-r", "--remap"):
            key, _, value = words[k + 1].partition(":=")
            if key == "__ns":
                ns = value.rstrip("/")
            elif key == "__node":
                name = value
    return f"{ns}/{name}"


class Session:
    """One document's commands: a work directory, the node it started, a ROS client."""

    def __init__(self, workdir: pathlib.Path) -> None:
        self.workdir = workdir
        shutil.copytree(ROOT / "examples", workdir / "examples")
        self.env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
                        ROS_HOME=str(workdir / "ros_home"),
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        self.env.pop("ROS_STATIC_PEERS", None)
        self.node: Optional[subprocess.Popen] = None
        self.node_name = ""
        self.node_log: Any = None
        self._ros: Any = None
        self.targets = _example_targets()

    # ROS
    @property
    def ros(self) -> Any:
        if self._ros is None:
            pytest.importorskip("rclpy")
            from ros_helpers import RosHarness

            self._ros = RosHarness()
        return self._ros

    def close(self) -> None:
        self.stop_node()
        if self._ros is not None:
            self._ros.stop()

    def stop_node(self) -> None:
        from rbc_registration.ros.process import stop_process

        if self.node is not None:
            stop_process(self.node)
            self.node = None
            self.node_log.close()

    def start_node(self, argv: list[str], name: str) -> None:
        """Start a node process (``argv``, in the work directory) and wait for its services."""
        self.stop_node()
        from std_srvs.srv import Trigger

        log_path = self.workdir / f"node{time.monotonic_ns()}.log"
        self.node_log = open(log_path, "w", encoding="utf-8")
        self.node = subprocess.Popen(argv, cwd=self.workdir, env=self.env,
                                     stdout=self.node_log, stderr=subprocess.STDOUT)
        self.node_name = name
        client = self.ros.client.create_client(Trigger, f"{name}/save")
        try:
            end = time.monotonic() + NODE_START_TIMEOUT_S
            while not client.wait_for_service(timeout_sec=0.5):
                assert self.node.poll() is None, (
                    f"{' '.join(argv)} ended with {self.node.returncode}:\n"
                    + log_path.read_text(encoding="utf-8"))
                assert time.monotonic() < end, f"{name} offers no services: {' '.join(argv)}"
        finally:
            self.ros.client.destroy_client(client)

    def status(self, node: str, after: float = 0.0) -> Any:
        """The latest latched ``~/status`` of ``node``."""
        from rbc_registration_interfaces.msg import RegistrationStatus
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        seen: list[Any] = []
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        sub = self.ros.client.create_subscription(RegistrationStatus, f"{node}/status",
                                                  seen.append, qos)
        try:
            from ros_helpers import wait_for

            wait_for(lambda: bool(seen)
                     and seen[-1].n_measurements + seen[-1].n_rejected >= after,
                     timeout=30.0, what=f"{node}/status")
            return seen[-1]
        finally:
            self.ros.client.destroy_subscription(sub)

    # the runners
    def run(self, command: str) -> None:
        how = kind(command)
        assert how != "unknown", f"unknown command: {command}"
        if how == "not run":
            return
        getattr(self, "do_" + how.replace(" ", "_"))(command)

    def do_env(self, command: str) -> None:
        script = f"{command} >/dev/null && command -v rbc-registration"
        done = subprocess.run(["bash", "-c", script], cwd=ROOT, capture_output=True, text=True,
                              timeout=COMMAND_TIMEOUT_S)
        assert done.returncode == 0, done.stderr
        found = pathlib.Path(done.stdout.strip())
        assert found.parent == ROOT / ".venv" / "bin", found

    def do_shell(self, command: str) -> None:
        done = subprocess.run(["bash", "-c", command], cwd=self.workdir, env=self.env,
                              capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
        assert done.returncode == 0, f"{command}: exit {done.returncode}\n{done.stderr}"
        bad = [line for line in done.stderr.splitlines()
               if "error" in line.lower() or "Traceback" in line]
        assert not bad, f"{command}:\n" + "\n".join(bad)
        assert done.stdout.strip(), f"{command}: printed nothing"

    def do_ros2_run(self, command: str) -> None:
        words = _words(command)
        exe = pathlib.Path(sys.prefix) / "lib" / words[2] / words[3]
        assert exe.is_file(), f"{command}: ros2 run finds no {exe}"
        self.do_shell(shlex.join([str(exe), *words[4:]]))

    def do_node(self, command: str) -> None:
        words = _words(command)
        if words[0] == "ros2":       # ros2 run rbc_registration registration_node ...
            exe = pathlib.Path(sys.prefix) / "lib" / words[2] / words[3]
            assert exe.is_file(), f"{command}: ros2 run finds no {exe}"
            words = [str(exe), *words[4:]]
        else:
            words = [str(BIN / words[0]), *words[1:]]
        self.start_node(words, _node_name(words))

    def do_launch(self, command: str) -> None:
        words = _words(command)
        path = ROOT / "launch" / words[3]
        assert path.is_file(), f"{command}: no launch/{words[3]}"
        given = dict(word.split(":=", 1) for word in words[4:])
        spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        declared = {a[0] for a in module.ARGUMENTS}
        assert set(given) <= declared, f"{command}: undeclared {set(given) - declared}"
        if hasattr(module, "included_arguments"):     # publish.launch.py
            given = module.included_arguments(given)
            spec = importlib.util.spec_from_file_location(
                "registration_launch", path.parent / module.INCLUDED)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        values = {name: default for name, default, _ in module.ARGUMENTS}
        values["params_file"] = str(ROOT / "config" / "registration_node.yaml")
        values.update(given)
        namespace, overrides = module.node_parameters(values, None, self.env)
        argv = [str(BIN / module.EXECUTABLE), "--ros-args", "-r", f"__ns:={namespace}",
                "-r", f"__node:={values['node_name']}", "--params-file", values["params_file"]]
        for key, value in overrides.items():
            text = str(value).lower() if isinstance(value, bool) else str(value)
            argv += ["-p", f"{key}:={text or chr(39) * 2}"]
        self.start_node(argv, _node_name(argv))

    def do_topic_pub(self, command: str) -> None:
        words = [w for w in _words(command)[3:] if w not in ("--once", "-1")]
        topic, type_name = words[0], words[1]
        message = fill(_message_type(type_name)(), yaml.safe_load(words[2]) if len(words) > 2
                       else None)
        assert self.node is not None, f"{command}: no node started before it"
        node = topic.rsplit("/", 1)[0]
        before = self.status(node)
        count = before.n_measurements + before.n_rejected
        publisher = self.ros.client.create_publisher(type(message), topic, 10)
        try:
            from ros_helpers import wait_for

            wait_for(lambda: publisher.get_subscription_count() > 0, 30.0, f"{topic} subscriber")
            if hasattr(message, "header"):
                message.header.stamp = self.ros.client.get_clock().now().to_msg()
            publisher.publish(message)
            after = self.status(node, after=count + 1)
        finally:
            self.ros.client.destroy_publisher(publisher)
        if type_name.endswith("/FiducialPair"):
            assert after.n_measurements == before.n_measurements + 1, (
                f"{command}: not accepted ({after.message})")

    def do_service_call(self, command: str) -> None:
        words = _words(command)[3:]
        service, type_name = words[0], words[1]
        srv = _message_type(type_name)
        request = fill(srv.Request(), yaml.safe_load(words[2]) if len(words) > 2 else None)
        assert self.node is not None, f"{command}: no node started before it"
        answer = self.ros.call(srv, service, request, timeout=60.0)
        if hasattr(answer, "success"):
            assert answer.success, f"{command}: {answer.message}"
        if type_name.endswith("/CorrectTarget"):
            self._check_target(command, request, answer)

    def _check_target(self, command: str, request: Any, answer: Any) -> None:
        point = request.target.point
        asked = [point.x, point.y, point.z]
        for source, working, truth in self.targets:
            if all(abs(a - w) < 1e-6 for a, w in zip(asked, working)):
                got = answer.destination.point
                error = math.dist([got.x, got.y, got.z][:len(truth)], truth)
                assert math.isfinite(answer.tre_bound), f"{command}: no bound"
                assert error <= answer.tre_bound, (
                    f"{command}: {error:.3g} m from the truth of {source}, "
                    f"beyond its 95 % bound {answer.tre_bound:.3g} m")
                return
        raise AssertionError(f"{command}: the target is no row of examples/*/targets.csv")


ROS_KINDS = {"node", "launch", "topic pub", "service call"}


def _runnable_docs() -> list[Any]:
    """The documents with a command to run; those with a ROS command marked ``ros``."""
    docs = []
    for path in DOCS:
        kinds = {kind(c) for _, c in doc_commands(path)} - {"not run"}
        needs_ros = bool(kinds & ROS_KINDS) or any(
            "node_client" in c or c.startswith("rbc-registration replay")
            for _, c in doc_commands(path))
        if kinds:
            docs.append(pytest.param(path, id=str(path.relative_to(ROOT)),
                                     marks=[pytest.mark.ros] if needs_ros else []))
    return docs


@pytest.mark.parametrize("doc", _runnable_docs())
def test_the_commands_of_the_doc_run(doc, tmp_path):
    session = Session(tmp_path)
    try:
        for number, command in doc_commands(doc):
            try:
                session.run(command)
            except AssertionError as error:
                raise AssertionError(f"{doc.relative_to(ROOT)}:{number}: {error}") from None
    finally:
        session.close()


# --- docs/CLI.md against the parser ----------------------------------------------------------

def _cli_sections() -> dict[str, str]:
    """docs/CLI.md's text per ``## `subcommand` `` section."""
    sections: dict[str, str] = {}
    name = None
    for line in (ROOT / "docs" / "CLI.md").read_text(encoding="utf-8").splitlines():
        heading = re.match(r"^## `([a-z-]+)`\s*$", line)
        if heading:
            name = heading.group(1)
            sections[name] = ""
        elif line.startswith("## "):
            name = None
        elif name:
            sections[name] += line + "\n"
    return sections


def _subcommand_options() -> dict[str, set[str]]:
    from rbc_registration.cli import build_parser

    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.choices and isinstance(a.choices, dict))
    return {name: {o for action in sub._actions for o in action.option_strings
                   if o.startswith("--") and o != "--help"}
            for name, sub in subparsers.choices.items()}


@pytest.mark.parametrize("name", ["register", "plan", "export", "reproduce"])
def test_cli_md_names_every_option_of_the_subcommand_and_no_other(name):
    """Every option of ``--help`` is named in the subcommand's section; every option of its
    options table is one the subcommand has."""
    text = _cli_sections()[name]
    options = _subcommand_options()[name]
    named = set(re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", text))
    missing = sorted(options - named)
    assert not missing, f"docs/CLI.md, `{name}`, does not name {missing}"
    table = "\n".join(line for line in text.splitlines() if line.startswith("| `--"))
    named = set(re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", table))
    unknown = sorted(named - options)
    assert not unknown, f"docs/CLI.md, `{name}`, names options {name} does not have: {unknown}"


def _table_keys(text: str, header: str) -> set[str]:
    """The keys of the first column of the table under the line ``header`` in ``text``."""
    lines = text.split(header, 1)[1].splitlines()
    keys: set[str] = set()
    for line in lines[1:]:
        if not line.strip():
            if keys:
                break
            continue
        if line.startswith("| ") and not line.startswith("| key") and "---" not in line:
            keys |= set(re.findall(r"`([A-Za-z_0-9]+)`", line.split("|")[1]))
    return keys


def _report(tmp_path: pathlib.Path, *argv: str) -> dict:
    import contextlib
    import io
    import json

    from rbc_registration.cli import main

    out = tmp_path / "report.json"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*argv, "--json", str(out)]) == 0
    return json.loads(out.read_text(encoding="utf-8"))


def test_cli_md_json_tables_name_the_keys_the_reports_have(tmp_path):
    cell = ROOT / "examples" / "cell3d"
    sections = _cli_sections()
    report = _report(tmp_path, "register", str(cell / "fiducials.csv"), "--targets",
                     str(cell / "targets.csv"), "--loo")
    documented = _table_keys(sections["register"], "### JSON report")
    evaluate_only = {"working_frame", "destination_frame"}
    assert set(report) <= documented, f"undocumented: {sorted(set(report) - documented)}"
    assert documented - evaluate_only <= set(report), sorted(documented - set(report))
    for key, header in (("decision", "`decision`:"), ("targets", "`targets[]`:")):
        keys = set(report[key] if key == "decision" else report[key][0])
        named = _table_keys(sections["register"], header)
        assert keys == named, f"{key}: undocumented {keys - named}, absent {named - keys}"

    # plan, once with the candidates alone and once in groups of two (a group column)
    rows = (cell / "candidates.csv").read_text(encoding="utf-8").splitlines()
    grouped = tmp_path / "grouped.csv"
    grouped.write_text("\n".join([rows[0] + ",group"] + [f"{r},P{k // 2}"
                                                         for k, r in enumerate(rows[1:])]),
                       encoding="utf-8")
    keys = set()
    for candidates in (cell / "candidates.csv", grouped):
        keys |= set(_report(tmp_path, "plan", str(cell / "fiducials.csv"), "--candidates",
                            str(candidates)))
    named = _table_keys(sections["plan"], "`plan --json` keys:")
    assert keys == named, f"undocumented {keys - named}, absent {named - keys}"


def _printed(*argv: str) -> list[str]:
    import contextlib
    import io

    from rbc_registration.cli import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(list(argv)) == 0, argv
    return [line.rstrip() for line in buffer.getvalue().splitlines()]


def _blocks(text: str, language: str) -> list[list[str]]:
    return [block.splitlines() for block in re.findall(rf"```{language}\n(.*?)```", text, re.S)]


NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def _same_line(shown: str, printed: str, rel: float = 1e-3) -> bool:
    """``shown`` is ``printed``: the same text, the same numbers to ``rel`` (numpy and scipy
    versions move the last digits)."""
    if NUMBER.sub("#", shown.rstrip()) != NUMBER.sub("#", printed):
        return False
    return all(math.isclose(float(a), float(b), rel_tol=rel, abs_tol=1e-9)
               for a, b in zip(NUMBER.findall(shown), NUMBER.findall(printed)))


def _not_printed(shown: list[str], printed: list[str]) -> list[str]:
    return [line for line in shown if not any(_same_line(line, p) for p in printed)]


def test_cli_md_output_excerpts_are_what_the_commands_print(tmp_path):
    """The ```text excerpt of register's output and the ```xml URDF joint of export are lines
    the commands print on the example cell, as they are now."""
    cell = ROOT / "examples" / "cell3d"
    report = tmp_path / "cell3d.json"
    printed = _printed("register", str(cell / "fiducials.csv"), "--targets",
                       str(cell / "targets.csv"), "--json", str(report))
    text = (ROOT / "docs" / "CLI.md").read_text(encoding="utf-8")
    (excerpt,) = _blocks(text, "text")
    missing = _not_printed(excerpt, printed)
    assert not missing, f"docs/CLI.md shows lines register does not print: {missing}"
    printed = _printed("export", str(report), "--out", str(tmp_path / "c.yaml"), "--urdf",
                       str(tmp_path / "c.urdf.xacro"), "--parent-frame", "world",
                       "--child-frame", "tracker")
    (joint,) = _blocks(text, "xml")
    missing = _not_printed(joint, printed)
    assert not missing, f"docs/CLI.md shows joint lines export does not print: {missing}"


def test_a_changed_figure_is_told_from_a_moved_last_digit():
    assert _same_line("x = 463.1212483 mm", "x = 463.1212485 mm")
    assert not _same_line("x = 463.1212483 mm", "x = 463.9 mm")
    assert not _same_line("x = 463.1212483 mm", "y = 463.1212483 mm")
