"""The paper's method as plain Python (numpy + scipy). Never imports rclpy.

Modules: :mod:`registration` (rigid fit), :mod:`mismatch` (L, sigma_L), :mod:`restoration`
(RBC restoration, eq. 4), :mod:`noise` (sigma, rho), :mod:`interpolation` and :mod:`kriging`
(eq. 5-6), :mod:`model` (everything together), :mod:`evaluation` (TRE, leave-one-out),
:mod:`synthetic` (cells modelled on the paper's experiments).
"""

from .evaluation import TargetErrors, leave_one_out, target_errors
from .model import ModelConfig, RbcModel, TargetCorrections, build_model
from .registration import Registration, rigid_fit
from .restoration import RestorationResult, restore_rigid_body

__all__ = ["ModelConfig", "RbcModel", "Registration", "RestorationResult", "TargetCorrections",
           "TargetErrors", "build_model", "leave_one_out", "restore_rigid_body", "rigid_fit",
           "target_errors"]
