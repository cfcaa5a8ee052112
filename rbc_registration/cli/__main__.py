"""``python -m rbc_registration.cli``: the ``rbc-registration`` command."""

import sys

from . import main

sys.exit(main())
