"""Which candidate to measure next, and when to stop (before measuring it, from the error model).

- :mod:`.planner`: the greedy plan: expected median target error per candidate (or pose),
  the sequence and the stopping rules' verdict.
- :mod:`.model_planner`: the plan of a built model (what the CLI and the node call).
- :mod:`.expected_error`: the expected target error of a fiducial layout, computable before
  measuring; :mod:`.rigid_tre`: the rigid fit's part of it and its growth beyond the fiducials.
- :mod:`.stopping`: the stopping rules (within F of every candidate, the gain) in one sentence.
- :mod:`.model_check`: whether the error model can be trusted: its expected held-out errors
  against the cross-validated ones, and the calibration from their ratio.
"""
