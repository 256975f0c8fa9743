"""Adapter of rule windows: all work is biasgt.workflow.steps.windows_step (unit-tested)."""

from biasgt.workflow.steps import run_step, windows_step

run_step(
    snakemake.log[0],  # noqa: F821
    windows_step,
    list(snakemake.input.stores),  # noqa: F821
    list(snakemake.input.recoveries),  # noqa: F821
    list(snakemake.input.validations),  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
