"""The ``biasgt`` command line: the parser and entry point (:mod:`biasgt.cli.app`) and one module
per subcommand (:mod:`biasgt.cli.commands`)."""
