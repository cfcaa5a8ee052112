"""The math never imports rclpy (checked in a fresh interpreter)."""

import pathlib
import subprocess
import sys

import rbc_registration

PKG = pathlib.Path(rbc_registration.__file__).parent


def test_core_and_io_do_not_import_rclpy():
    modules = sorted(f"rbc_registration.{sub}.{p.stem}" for sub in ("core", "io")
                     for p in (PKG / sub).glob("*.py") if p.stem != "__init__")
    modules += ["rbc_registration.cli", "rbc_registration.commands", "rbc_registration.reproduce"]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "bad = [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py')]\n"
            + "print(bad); sys.exit(1 if bad else 0)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert len(modules) >= 12
