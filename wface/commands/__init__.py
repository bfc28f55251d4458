"""Sub-commands of the ``wface`` CLI, one module each (see ``wface.cli``)."""
