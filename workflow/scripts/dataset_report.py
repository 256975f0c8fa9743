"""Adapter of rule dataset_report: all work is biasgt.workflow.steps.dataset_report_step (unit-tested)."""

from biasgt.workflow.steps import dataset_report_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    dataset_report_step,
    snakemake.params.results,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
