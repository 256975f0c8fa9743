"""Adapter of rule interpolate: all work is biasgt.workflow.steps.interpolate_step (unit-tested)."""

from biasgt.workflow.steps import interpolate_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    interpolate_step,
    snakemake.input.recovery,  # noqa: F821
    snakemake.input.store,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
