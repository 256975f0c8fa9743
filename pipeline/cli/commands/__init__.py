"""Subcommands of the ``biasgt`` CLI, one module each (see :mod:`pipeline.cli`)."""
