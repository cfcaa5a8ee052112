"""The paper's method as plain Python (numpy + scipy). Never imports rclpy.

The method's parts, one subpackage each (each with its own map):

- :mod:`.rigid`: the rigid fit (eq. 2), the mismatch (eq. 1, 7) and the restoration of the
  rigid-body condition (eq. 4), set-up errors between the frames, quaternions.
- :mod:`.interpolation`: a target's correction from the fiducials' (eqs. 5-6): the paper's
  interpolation and kriging.
- :mod:`.decision`: whether and how to correct: cross-validation, groups, the paired test,
  the 95 % bound, sigma and rho.
- :mod:`.planning`: which candidate to measure next, and when to stop.
- :mod:`.measurements`: measurements accumulated per fiducial: the checks, repeats, pairing,
  sessions.
- :mod:`.synthetic`: cells modelled on the paper's experiments.

What every part shares stays here: :mod:`.model` (everything together, ``build_model``),
:mod:`.config` (``ModelConfig``), :mod:`.answers` (one call's answers for targets),
:mod:`.saved_model` (a model's answers as saved in a calibration), :mod:`.warnings` (the
model's warning lines), :mod:`.validation` (the input checks), :mod:`.constants` (the closed
sets and shared rules, numpy-free), :mod:`.errors` (the exceptions), :mod:`.frames` (the tf
frame-id rule), :mod:`.compat` (numpy/scipy version differences).

The names below are loaded on first use, so importing :mod:`.constants` alone (as the
command-line parser does) does not load numpy or scipy. A module's path before the parts
(``rbc_registration.core.registration``, ...) still imports it: :data:`MOVED` maps each such
path to the module's place, and importing the old path gives the same module object.
"""

import importlib
import importlib.abc
import importlib.util
import sys
from importlib import import_module

_EXPORTS = {"TargetErrors": "decision.evaluation", "leave_one_out": "decision.evaluation",
            "target_errors": "decision.evaluation", "ModelConfig": "model", "RbcModel": "model",
            "TargetCorrections": "model", "build_model": "model",
            "Registration": "rigid.registration", "rigid_fit": "rigid.registration",
            "RestorationResult": "rigid.restoration",
            "restore_rigid_body": "rigid.restoration", "Decision": "decision.choice",
            "DecisionMode": "constants", "CANDIDATES": "constants"}

__all__ = sorted(_EXPORTS)

#: The modules that moved into the parts: old name (in this package) -> place.
MOVED = {
    "registration": "rigid.registration", "mismatch": "rigid.mismatch",
    "restoration": "rigid.restoration", "gauss_newton": "rigid.gauss_newton",
    "scale": "rigid.scale", "quaternion": "rigid.quaternion",
    "sectors": "interpolation.sectors", "sector_grid": "interpolation.sector_grid",
    "kriging": "interpolation.kriging", "gp_fit": "interpolation.gp_fit",
    "kriging_summary": "interpolation.kriging_summary",
    "blocked_linalg": "interpolation.blocked_linalg",
    "crossval": "decision.crossval", "evaluation": "decision.evaluation",
    "groups": "decision.groups", "noise": "decision.noise",
    "synthetic_structure": "synthetic.structure", "experiments": "synthetic.experiments",
    "accumulator": "measurements.accumulator", "records": "measurements.records",
    "measurement_checks": "measurements.checks", "pairing": "measurements.pairing",
    "sessions": "measurements.sessions", "session_sums": "measurements.session_sums",
    "planner": "planning.planner", "model_planner": "planning.model_planner",
    "expected_error": "planning.expected_error", "rigid_tre": "planning.rigid_tre",
    "stopping": "planning.stopping", "model_check": "planning.model_check",
}


def names_of(package: str, module: str):
    """A package's ``__getattr__`` that gives the names of its ``module`` on first use (the
    parts named as the module they replace: ``interpolation``, ``decision``, ``synthetic``)."""

    def forward(name: str):
        if name.startswith("__"):
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{module}"), name)

    return forward


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``rbc_registration.core.<old>`` of :data:`MOVED` as the module at its place."""

    def find_spec(self, fullname, path=None, target=None):
        prefix, _, old = fullname.rpartition(".")
        if prefix == __name__ and old in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        module = import_module(f"{__name__}.{MOVED[spec.name.rpartition('.')[2]]}")
        spec.loader_state = module.__spec__      # importlib replaces it on the module next
        return module

    def exec_module(self, module):
        # executed at its place already: give it back its own spec and loader
        own = module.__spec__.loader_state
        module.__spec__, module.__loader__ = own, own.loader


if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.append(_MovedModules())
