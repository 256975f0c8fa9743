"""Adapter of rule ingest: all work is biasgt.workflow.steps.ingest_step (unit-tested)."""

from biasgt.workflow.steps import ingest_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    ingest_step,
    snakemake.input.source,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
