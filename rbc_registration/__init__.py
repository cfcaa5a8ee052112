"""rbc_registration: rigid-body registration improved by restoring the rigid-body condition."""
