"""rbc_registration: rigid-body registration improved by restoring the rigid-body condition."""

from .core.errors import InputError, OperationError, RegistrationError

__all__ = ["InputError", "OperationError", "RegistrationError"]
