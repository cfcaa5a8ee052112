"""Whether and how to correct: held-out errors, the paired test, the bound, rho.

- :mod:`.choice`: the decision (``Decision``, ``decide``), its error model and 95 % bound.
- :mod:`.crossval`: each candidate's held-out errors (leave-one-out or k folds).
- :mod:`.groups`: fiducials that share one error, held out whole.
- :mod:`.evaluation`: TRE of targets with truth, leave-one-out, blunders.
- :mod:`.noise`: sigma from repeats and the paper's rho = sigma_L0 / sigma (section 6).

The names of :mod:`.choice` are importable from this package too
(``from rbc_registration.core.decision import Decision``).
"""

from .. import names_of

__getattr__ = names_of(__name__, "choice")
