"""Adapter of rule table: all work is biasgt.workflow.learning.table_step (unit-tested)."""

from pathlib import Path

from biasgt.workflow.learning import table_step
from biasgt.workflow.steps import run_step

run_step(
    snakemake.log[0],  # noqa: F821
    table_step,
    list(snakemake.input.evaluations),  # noqa: F821
    str(Path(snakemake.output[0]).parent),  # noqa: F821
)
