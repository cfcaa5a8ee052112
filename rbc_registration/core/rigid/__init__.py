"""The rigid fit and the restoration of the rigid-body condition (paper eqs. 1-4).

- :mod:`.registration`: the proper rigid fit minimising the FRE (eq. 2), ``Registration``.
- :mod:`.mismatch`: the pairwise distance mismatch L_ij (eq. 1) and sigma_L (eq. 7).
- :mod:`.restoration`: corrections eps_j that make every pairwise distance match (eq. 4);
  :mod:`.gauss_newton`: its minimum-norm Gauss-Newton step.
- :mod:`.scale`: set-up errors between the frames (units, scale, a tilted plate) and rigidity.
- :mod:`.quaternion`: rotations as tf2's quaternions and REP 103 roll, pitch, yaw.
"""
