"""Snakemake glue: everything the workflow (``Snakefile`` and ``workflow/rules/*.smk``) needs, as plain,
importable and unit-tested Python, so that the ``.smk`` files only wire rules together.

* :mod:`~pipeline.workflow.table`: the parsed sequence table (:class:`~pipeline.workflow.table.WorkflowConfig`).
* :mod:`~pipeline.workflow.config`: reading and checking a workflow config (schema, then what a
  schema cannot say).
* :mod:`~pipeline.workflow.params`: the rules' parameters and inputs (the ``get_*`` functions of
  ``workflow/rules/common.smk``).
* :mod:`~pipeline.workflow.steps`: what the thin scripts under ``workflow/scripts/`` call.
* :mod:`~pipeline.workflow.learning`: the learning stage's result paths and steps (train, evaluate,
  Table I) over the :mod:`training` library.
* :mod:`~pipeline.workflow.run`: ``biasgt run`` (Snakemake in a subprocess), with
  :mod:`~pipeline.workflow.process_group`, :mod:`~pipeline.workflow.job_progress` and
  :mod:`~pipeline.workflow.run_summary`.


Layout of a workflow run (relative to the working directory)::

    results/<folder>/<sequence>/...  one folder per stage and sequence (:attr:`Stage.folder`:
                                     simulate, ingest, recovery, interpolation, validation, report)
    results/windows/dataset/         the window dataset of the train / val / test sequences
    logs/<folder>/<sequence>.log     the log of that job (logs/windows/dataset.log)
"""
