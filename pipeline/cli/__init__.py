"""The ``biasgt`` command line: the parser and entry point (:mod:`pipeline.cli.app`) and one module
per subcommand (:mod:`pipeline.cli.commands`)."""
