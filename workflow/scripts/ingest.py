"""Adapter of rule ingest: all work is pipeline.workflow.steps.ingest_step (unit-tested)."""

from pipeline.workflow.steps import ingest_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    ingest_step,
    snakemake.input.source,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
