"""The biasgt application: the top layer, above the stages and the core.

* :mod:`biasgt.cli`: the ``biasgt`` command (the parser, one thin module per subcommand);
* :mod:`biasgt.workflow`: the workflow glue (checked config, rule parameters, step functions,
  ``biasgt run``).

Nothing below this package imports it; the library itself is ``pipeline`` (core), ``recovery``,
``interpolation``, ``validation``, ``training`` and ``reports`` (the stages).
"""
