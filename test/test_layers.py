"""The layers of the package and the arrows between them: cli, ros -> io -> pipeline -> core.

- Every module of ``core``, ``pipeline``, ``io`` and ``cli`` imports, in a fresh interpreter,
  neither rclpy nor any ROS message or middleware package.
- No module imports a layer above its own (checked on the source: every import statement,
  including the ones inside functions).
- Building the command-line parser loads neither numpy nor anything heavy (``--help`` is instant).
"""

import ast
import importlib.metadata
import os
import pathlib
import subprocess
import sys

import rbc_registration

PKG = pathlib.Path(rbc_registration.__file__).parent

#: What each layer (or top-level module) may import from the package.
ALLOWED = {
    "runtime": set(),
    "core": {"core"},
    "pipeline": {"core", "pipeline"},
    "io": {"core", "pipeline", "io"},
    "ros": {"core", "pipeline", "io", "ros", "runtime"},
    "cli": {"core", "pipeline", "io", "cli", "ros", "runtime"},
}
PURE_LAYERS = ("core", "pipeline", "io", "cli")
#: Top-level names of ROS 2 packages whatever installed them (a sourced ROS, colcon, wheels).
ROS_NAMES = {"rclpy", "rcl_interfaces", "builtin_interfaces", "std_msgs", "geometry_msgs",
             "std_srvs", "sensor_msgs", "diagnostic_msgs", "visualization_msgs", "tf2_ros",
             "tf2_msgs", "tf2_py", "rbc_registration_interfaces", "rosidl_runtime_py",
             "rosidl_parser", "rpyutils", "ament_index_python", "action_msgs", "service_msgs",
             "unique_identifier_msgs", "type_description_interfaces", "rosgraph_msgs",
             "lifecycle_msgs", "launch", "launch_ros", "rosbag2_py", "message_filters"}


def ros_module_names():
    """:data:`ROS_NAMES` plus every top-level module installed by a ``ros-*`` wheel (except the
    wheels' start-up hook, which every Python of the venv runs before any code)."""
    names = set(ROS_NAMES)
    for module, dists in importlib.metadata.packages_distributions().items():
        if any(d.lower().startswith("ros-") for d in dists):
            names.add(module)
    names.discard("ros_wheels_bootstrapper")
    return names


def modules_of(layer):
    base = PKG / layer
    return sorted("rbc_registration." + ".".join(p.relative_to(PKG).with_suffix("").parts)
                  .removesuffix(".__init__") for p in base.rglob("*.py")
                  if p.stem != "__main__")


def test_core_pipeline_io_and_cli_import_no_ros_package():
    modules = [m for layer in PURE_LAYERS for m in modules_of(layer)]
    assert len(modules) >= 40 and "rbc_registration.pipeline.worker" in modules
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + f"ros = {sorted(ros_module_names())!r}\n"
            + "bad = sorted(m for m in sys.modules if m.split('.')[0] in ros or "
              "m.split('.')[0].startswith(('rosidl', 'rcl', 'rmw', 'tf2')))\n"
            + "print(bad); sys.exit(1 if bad else 0)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def imported_layers(path):
    """(line, layer) of every import of ``rbc_registration.<layer>`` in the file at ``path``."""
    parts = path.relative_to(PKG).with_suffix("").parts
    package = ["rbc_registration", *parts[:-1]]   # the package a relative import starts from
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                names = [".".join(base + ([node.module] if node.module else []))]
                if not node.module:
                    names = [".".join(base + [a.name]) for a in node.names]
            else:
                names = [node.module or ""]
        else:
            continue
        for name in names:
            bits = name.split(".")
            if bits[0] == "rbc_registration" and len(bits) > 1:
                out.append((node.lineno, bits[1]))
    return out


def test_imports_point_down_only():
    wrong = []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG)
        layer = rel.parts[0].removesuffix(".py")
        if layer == "__init__":
            continue
        assert layer in ALLOWED, f"{rel}: a module outside the known layers"
        for line, target in imported_layers(path):
            if target not in ALLOWED[layer]:
                wrong.append(f"{rel}:{line} ({layer}) imports rbc_registration.{target}")
    assert wrong == []


#: The method's parts (subpackages of core) and the other parts each may import; every part may
#: import itself and the modules at core's root (what the parts share), and the root may import
#: every part.
CORE_PARTS = {
    "rigid": set(),
    "interpolation": {"rigid"},
    "decision": {"rigid", "interpolation"},
    "measurements": {"rigid", "decision"},
    "planning": {"rigid", "interpolation", "decision"},
    "synthetic": {"rigid", "interpolation", "decision", "measurements", "planning"},
}
CORE = PKG / "core"


def core_part_imports(path):
    """(line, part) of every import of a core part in the file at ``path`` (core's root modules
    as ``""``)."""
    parts = path.relative_to(PKG).with_suffix("").parts
    package = ["rbc_registration", *parts[:-1]]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            mod = base + (node.module.split(".") if node.module else [])
            names = [mod] if node.module else [mod + [a.name] for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".") for a in node.names]
        else:
            continue
        for bits in names:
            if bits[:2] == ["rbc_registration", "core"] and len(bits) > 2:
                out.append((node.lineno, bits[2] if bits[2] in CORE_PARTS else ""))
    return out


def test_the_parts_of_core_import_as_the_method_builds_on_itself():
    present = sorted(p.name for p in CORE.iterdir() if (p / "__init__.py").exists())
    assert present and set(present) <= set(CORE_PARTS), present
    root_modules = [p for p in CORE.glob("*.py") if p.name != "__init__.py"]
    assert len(root_modules) <= 12, sorted(p.name for p in root_modules)
    wrong = []
    for part in present:
        for path in sorted((CORE / part).rglob("*.py")):
            for line, target in core_part_imports(path):
                if target and target != part and target not in CORE_PARTS[part]:
                    wrong.append(f"{path.relative_to(PKG)}:{line} ({part}) imports {target}")
    assert wrong == []


def test_the_parser_loads_no_numpy():
    code = ("import sys\nfrom rbc_registration import cli\ncli.build_parser()\n"
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'scipy', 'matplotlib', 'rosbags'))\nprint(heavy); sys.exit(bool(heavy))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_the_entry_point_defaults_to_one_blas_thread_before_numpy(tmp_path):
    """``rbc-registration`` sets OPENBLAS_NUM_THREADS=1 before a subcommand loads numpy (unless
    the user set it), so it takes effect; a user's value is kept."""
    code = ("import os, sys\nfrom rbc_registration import cli\n"
            "assert 'numpy' not in sys.modules\n"
            "code = cli.main(['synth-bag', '--cell', 'RA', sys.argv[1], '--quiet'])\n"
            "assert 'numpy' in sys.modules\n"
            "print(os.environ.get('OPENBLAS_NUM_THREADS')); sys.exit(code)\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "a")], env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.splitlines()[-1] == "1", proc.stdout + proc.stderr
    env["OPENBLAS_NUM_THREADS"] = "2"
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "b")], env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.splitlines()[-1] == "2", proc.stdout + proc.stderr


def test_freeze_startup_objects_collects_first_then_freezes():
    """``registration_node`` freezes what its start created (runtime.freeze_startup_objects):
    garbage of the start is collected first, the rest leaves the cyclic collector's scans."""
    code = ("import gc, weakref\nfrom rbc_registration.runtime import freeze_startup_objects\n"
            "class C: pass\n"
            "a = C(); a.me = a; dead = weakref.ref(a); del a\n"      # cyclic garbage
            "keep = [C() for _ in range(1000)]\n"
            "n = freeze_startup_objects()\n"
            "assert dead() is None, 'garbage frozen'\n"
            "assert n == gc.get_freeze_count() > 1000, n\n"
            "scanned = {id(o) for o in gc.get_objects()}\n"
            "assert not any(id(k) in scanned for k in keep), 'not frozen'\n"
            "later = C(); assert id(later) in {id(o) for o in gc.get_objects()}\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
