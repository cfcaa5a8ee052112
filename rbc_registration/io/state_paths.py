"""The default ``state_dir`` of a node, where launch files and user code import it:
:mod:`rbc_registration.pipeline.state_dir` holds it (and the :class:`StateDir` of its files)."""

from ..pipeline.state_dir import (STATE_ROOT, check_node_name, default_state_dir,
                                  resolve_namespace, state_dir_name, state_root)

__all__ = ["STATE_ROOT", "check_node_name", "default_state_dir", "resolve_namespace",
           "state_dir_name", "state_root"]
