"""Adapter of rule simulate: all work is biasgt.workflow.steps.simulate_step (unit-tested)."""

from biasgt.workflow.steps import run_step, simulate_step

run_step(snakemake.log[0], simulate_step, snakemake.params.settings, snakemake.output[0])  # noqa: F821
