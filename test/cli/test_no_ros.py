"""The offline path needs no ROS: in a fresh interpreter where every ROS module (rclpy, the
message packages, rosidl, tf2, ...) is blocked by a meta-path finder and no ROS prefix is set,
``synth-bag``, ``evaluate`` (sqlite3 and mcap), ``register``, ``plan`` (with its figure) and a
small ``reproduce`` all succeed, and not one ROS module was imported. ``replay``, which needs the
message packages and rclpy, fails with one clear line instead of a traceback."""

import json
import os
import subprocess
import sys

from test_layers import ros_module_names

SCRIPT = r'''
import importlib.abc, json, sys
ROS = set(json.loads(sys.argv[1]))
PREFIXES = ("rosidl", "rcl", "rmw", "tf2")


def is_ros(name):
    top = name.split(".")[0]
    return top in ROS or top.startswith(PREFIXES)


class BlockRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if is_ros(name):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked: no ROS here)",
                                      name=name)
        return None


sys.meta_path.insert(0, BlockRos())
from rbc_registration.cli import main
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.csv_io import write_fiducials, write_targets

out = sys.argv[2]
runs = []
for storage in ("sqlite3", "mcap"):
    bag = f"{out}/ra_{storage}"
    runs.append(["synth-bag", "--cell", "RA", bag, "--storage", storage, "--quiet"])
    runs.append(["evaluate", bag, "--quiet", "--json", f"{bag}.json", "--out", f"{bag}_report"])
cell = make_cell("A", seed=2, repeats=3)
write_fiducials(f"{out}/fid.csv", cell.fiducial_ids, cell.fiducial_measurements,
                [t[None] for t in cell.fiducial_truth])
write_targets(f"{out}/tgt.csv", cell.target_ids, cell.target_means, cell.target_truth)
runs.append(["register", f"{out}/fid.csv", "--targets", f"{out}/tgt.csv", "--loo",
             "--json", f"{out}/register.json"])
runs.append(["plan", f"{out}/fid.csv", "--candidates", f"{out}/tgt.csv", "--count", "2",
             "--json", f"{out}/plan.json", "--figure", f"{out}/plan.png"])
runs.append(["reproduce", "--cells", "RA", "--repeats", "2", "--out", f"{out}/reproduce"])
for argv in runs:
    code = main(argv)
    print(f"== {argv[0]} -> {code}", flush=True)
    if code != 0:
        sys.exit(f"{argv} exited {code}")
code = main(["replay", f"{out}/ra_mcap", "--quiet"])
print(f"== replay -> {code}", flush=True)
loaded = sorted(m for m in sys.modules if is_ros(m))
print("ROS modules loaded:", loaded)
sys.exit(1 if loaded or code != 2 else 0)
'''


def test_offline_commands_work_with_every_ros_module_blocked(tmp_path):
    env = {k: v for k, v in os.environ.items()
           if k not in ("AMENT_PREFIX_PATH", "RBC_MSG_DIR", "PYTHONPATH")}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(sorted(ros_module_names())),
                           str(tmp_path)], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    for name in ("synth-bag", "evaluate", "register", "plan", "reproduce"):
        assert f"== {name} -> 0" in proc.stdout
    assert "== replay -> 2" in proc.stdout and "ROS modules loaded: []" in proc.stdout
    assert "rbc-registration replay: error: bag " in proc.stderr
    assert "no messages to replay (no Python message type for" in proc.stderr
    assert "Traceback" not in proc.stderr
    for storage in ("sqlite3", "mcap"):
        report = json.loads((tmp_path / f"ra_{storage}.json").read_text())
        assert report["n_fiducials"] == 277 and report["dim"] == 2
        assert (tmp_path / f"ra_{storage}_report" / "report.md").exists()
    assert json.loads((tmp_path / "ra_sqlite3.json").read_text())["corrected"] == json.loads(
        (tmp_path / "ra_mcap.json").read_text())["corrected"]
    assert json.loads((tmp_path / "register.json").read_text())["loo"]["fiducials"]
    assert (tmp_path / "reproduce" / "reproduce.json").exists()
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert len(plan["suggestions"]) == 2 and plan["dim"] == 3 and plan["n_candidates"] == 16
    assert (tmp_path / "plan.png").read_bytes()[:4] == b"\x89PNG"
