"""Adapter of rule validate: all work is biasgt.workflow.steps.validate_step (unit-tested).

A FAIL verdict is written and the job succeeds; only bad inputs fail the job.
"""

from biasgt.workflow.steps import run_step, validate_step

run_step(
    snakemake.log[0],  # noqa: F821
    validate_step,
    snakemake.input.store,  # noqa: F821
    snakemake.input.recovery,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
)
