"""Measurements accumulated per fiducial, live and offline, and the rules each one passes.

- :mod:`.accumulator`: the running sums per fiducial (means, repeats) the node and the offline
  tools share; :mod:`.records`: its records (accepted and rejected measurements, fiducial sets).
- :mod:`.checks`: the id, stamp, age and coordinate rules of one measurement.
- :mod:`.pairing`: working and destination points published separately, paired by stamp.
- :mod:`.sessions`: sessions between which the working frame moved (the motion, its F test,
  the re-stationing, the live bump detector); :mod:`.session_sums`: the accumulator's sums per
  session.
"""
