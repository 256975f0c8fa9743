"""Adapter of rule train: all work is biasgt.workflow.learning.train_step (unit-tested)."""

from biasgt.workflow.learning import train_step
from biasgt.workflow.steps import run_step

run_step(
    snakemake.log[0],  # noqa: F821
    train_step,
    snakemake.input.dataset,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.config,  # noqa: F821
    threads=snakemake.threads,  # noqa: F821
    processes=snakemake.params.processes,  # noqa: F821
)
