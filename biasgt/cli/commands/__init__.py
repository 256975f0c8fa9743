"""Subcommands of the ``biasgt`` CLI, one module each (see :mod:`biasgt.cli`)."""
