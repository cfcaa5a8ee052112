"""The real build child, whose model states hold something pickle cannot write
(test_build_process: a result the child cannot send back is built in the thread). Run as
``python -m unsendable_build_child`` with this directory on PYTHONPATH."""

import dataclasses
import sys

import rbc_registration.pipeline.state as state
from rbc_registration.pipeline.build_child import main

_build_state = state.build_state


def _unsendable(*args, **kwargs):
    return dataclasses.replace(_build_state(*args, **kwargs), warning=lambda: "")


if __name__ == "__main__":
    state.build_state = _unsendable
    sys.exit(main())
