"""The paper's method as plain Python (numpy + scipy). Never imports rclpy.

Modules: :mod:`registration` (rigid fit), :mod:`mismatch` (L, sigma_L), :mod:`restoration`
(RBC restoration, eq. 4; :mod:`gauss_newton`: its step), :mod:`noise` (sigma in both
conventions, rho), :mod:`interpolation` (:mod:`sectors`, :mod:`sector_grid`: the 2D rule) and
:mod:`kriging` (eq. 5-6; :mod:`gp_fit` fits kriging), :mod:`crossval` and :mod:`decision`
(whether and how to correct, expected error), :mod:`model` (everything together;
:mod:`answers`: what it answers for targets),
:mod:`evaluation` (TRE, leave-one-out), :mod:`synthetic` (cells modelled on the paper's
experiments), :mod:`constants` (the closed sets and shared rules, numpy-free).

The names below are loaded on first use, so importing :mod:`.constants` alone (as the
command-line parser does) does not load numpy or scipy.
"""

from importlib import import_module

_EXPORTS = {"TargetErrors": "evaluation", "leave_one_out": "evaluation",
            "target_errors": "evaluation", "ModelConfig": "model", "RbcModel": "model",
            "TargetCorrections": "model", "build_model": "model", "Registration": "registration",
            "rigid_fit": "registration", "RestorationResult": "restoration",
            "restore_rigid_body": "restoration", "Decision": "decision",
            "DecisionMode": "constants", "CANDIDATES": "constants"}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
