"""Adapter of rule recover: all work is biasgt.workflow.steps.recover_step (unit-tested)."""

from biasgt.workflow.steps import recover_step, run_step

run_step(
    snakemake.log[0],  # noqa: F821
    recover_step,
    snakemake.input.store,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
