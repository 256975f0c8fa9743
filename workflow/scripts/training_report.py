"""Adapter of rule training_report: all work is reports.training.build_training_report (unit-tested)."""

from biasgt.workflow.steps import run_step
from reports.training import build_training_report

run_step(
    snakemake.log[0],  # noqa: F821
    build_training_report,
    list(snakemake.input.evaluations),  # noqa: F821
    list(snakemake.input.runs),  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
