"""Adapter of rule train: all work is pipeline.workflow.learning.train_step (unit-tested)."""

from pipeline.workflow.learning import train_step
from pipeline.workflow.steps import run_step

run_step(
    snakemake.log[0],  # noqa: F821
    train_step,
    snakemake.input.dataset,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.config,  # noqa: F821
    threads=snakemake.threads,  # noqa: F821
    processes=snakemake.params.processes,  # noqa: F821
)
