"""The package's exceptions: one base, so a caller of the library can catch every error it
raises on purpose (``except RegistrationError``).

- :class:`RegistrationError`: the base.
- :class:`InputError`: bad input (points, a file, a message, a parameter); the message names
  what was wrong in one line. It is a ``ValueError`` too, so callers that catch ``ValueError``
  keep working.
- :class:`OperationError`: an operation that could not complete (a build process that died or
  was cancelled, a demo step that failed); a ``RuntimeError`` too.

The classes of the layers derive from these (:class:`~rbc_registration.io.csv_io.CsvError`,
:class:`~rbc_registration.io.bag.records.BagError`,
:class:`~rbc_registration.core.measurements.records.RejectedMeasurement`,
:class:`~rbc_registration.pipeline.journal_records.JournalMismatch`,
:class:`~rbc_registration.pipeline.files.StateDirBusy`, ...).
"""

from __future__ import annotations

__all__ = ["InputError", "OperationError", "RegistrationError"]


class RegistrationError(Exception):
    """Base of every exception rbc_registration raises on purpose."""


class InputError(RegistrationError, ValueError):
    """Bad input; the message names what was wrong."""


class OperationError(RegistrationError, RuntimeError):
    """An operation that could not complete; the message says why."""
