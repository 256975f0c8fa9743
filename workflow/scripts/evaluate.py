"""Adapter of rules evaluate and evaluate_reference: all work is biasgt.workflow.learning.evaluate_step (unit-tested)."""

from biasgt.workflow.learning import evaluate_step
from biasgt.workflow.steps import run_step

wildcards = snakemake.wildcards  # noqa: F821
run_step(
    snakemake.log[0],  # noqa: F821
    evaluate_step,
    snakemake.input.dataset,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    run_dir=getattr(snakemake.input, "run", None),  # noqa: F821
    method=getattr(wildcards, "method", None),
    reference=getattr(wildcards, "reference", None),
    threads=snakemake.threads,  # noqa: F821
)
