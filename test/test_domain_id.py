"""The ROS domain of a test process (test/conftest.py) and of a shell (scripts/env.sh): a
ROS_DOMAIN_ID the user set is honoured; unset, each process chooses its own from its pid, and a
value chosen so by a parent (recorded in RBC_CHOSEN_ROS_DOMAIN_ID) is not taken for the user's."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VAR = "RBC_CHOSEN_ROS_DOMAIN_ID"
#: Loads test/conftest.py in a fresh interpreter (no pytest run) and prints what it chose.
PROBE = ("import importlib.util, os, sys; spec = importlib.util.spec_from_file_location("
         "'probe_conftest', sys.argv[1]); m = importlib.util.module_from_spec(spec); "
         "spec.loader.exec_module(m); print(m.ROS_DOMAIN_ID, os.environ['ROS_DOMAIN_ID'], "
         f"os.environ.get('{VAR}', ''), os.getpid(), sep='|')")


def _env(**values):
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_DOMAIN_ID", VAR)}
    env.update(values)
    return env


def _conftest(**values):
    out = subprocess.run([sys.executable, "-c", PROBE, str(ROOT / "test" / "conftest.py")],
                         env=_env(**values), capture_output=True, text=True, check=True)
    chosen, exported, recorded, pid = out.stdout.strip().split("|")
    return int(chosen), exported, recorded, int(pid)


def test_conftest_honours_a_domain_the_user_set():
    assert _conftest(ROS_DOMAIN_ID="142")[:3] == (142, "142", "")
    # the user's value wins even where a chooser recorded another
    assert _conftest(ROS_DOMAIN_ID="7", **{VAR: "8"})[:3] == (7, "7", "8")


def test_conftest_chooses_one_per_process_when_unset():
    domain, exported, recorded, pid = _conftest()
    assert domain == pid % 101 + 1 and exported == recorded == str(domain)
    # a value a parent chose (scripts/env.sh, an outer test process) is not the user's
    domain, exported, recorded, pid = _conftest(ROS_DOMAIN_ID="55", **{VAR: "55"})
    assert domain == pid % 101 + 1 and exported == recorded == str(domain)


def _env_sh(**values):
    out = subprocess.run(["bash", "-c", 'source scripts/env.sh >/dev/null 2>&1; '
                          f'echo "$ROS_DOMAIN_ID|${{{VAR}:-}}|$$"'], cwd=ROOT,
                         env=_env(**values), capture_output=True, text=True, check=True)
    return out.stdout.strip().split("|")


def test_env_sh_honours_the_users_domain_and_records_its_own_choice():
    domain, recorded, _ = _env_sh(ROS_DOMAIN_ID="142")
    assert (domain, recorded) == ("142", "")
    for values in ({}, {"ROS_DOMAIN_ID": "55", VAR: "55"}):
        domain, recorded, pid = _env_sh(**values)
        assert domain == recorded == str(int(pid) % 101 + 1)
