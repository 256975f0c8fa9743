"""Adapter of rule report: all work is biasgt.workflow.steps.report_step (unit-tested)."""

from biasgt.workflow.steps import report_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    report_step,
    snakemake.input.store,  # noqa: F821
    snakemake.input.recovery,  # noqa: F821
    snakemake.input.validation,  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
