"""Snakemake glue: everything the workflow (``Snakefile`` and ``workflow/rules/*.smk``) needs, as plain,
importable and unit-tested Python, so that the ``.smk`` files only wire rules together.

* :mod:`~biasgt.workflow.table`: the parsed sequence table (:class:`~biasgt.workflow.table.WorkflowConfig`).
* :mod:`~biasgt.workflow.config`: reading and checking a workflow config (schema, then what a
  schema cannot say).
* :mod:`~biasgt.workflow.params`: the rules' parameters and inputs (the ``get_*`` functions of
  ``workflow/rules/common.smk``).
* :mod:`~biasgt.workflow.steps`: what the thin scripts under ``workflow/scripts/`` call.
* :mod:`~biasgt.workflow.learning`: the learning stage's result paths and steps (train, evaluate,
  Table I) over the :mod:`training` library.
* :mod:`~biasgt.workflow.run`: ``biasgt run`` (Snakemake in a subprocess), with
  :mod:`~biasgt.workflow.process_group`, :mod:`~biasgt.workflow.job_progress` and
  :mod:`~biasgt.workflow.run_summary`.


Layout of a workflow run (relative to the working directory)::

    results/<folder>/<sequence>/...  one folder per stage and sequence (:attr:`Stage.folder`:
                                     simulate, ingest, recovery, interpolation, validation, report)
    results/windows/dataset/         the window dataset of the train / val / test sequences
    logs/<folder>/<sequence>.log     the log of that job (logs/windows/dataset.log)
"""
