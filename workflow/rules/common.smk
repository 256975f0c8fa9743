# Config validation, the sequence table and every input function (get_*) of the workflow.
# The logic lives in biasgt/workflow/ (unit-tested); these are one-line adapters.

import os

from biasgt.workflow import config as wf_config  # not 'config': that is Snakemake's config dict
from biasgt.workflow import params as wf


def _config_file():
    """The config file relative paths resolve against: the last --configfile, else the default."""
    files = list(workflow.overwrite_configfiles or []) or list(workflow.configfiles)
    return files[-1] if files else None


# One validator for 'biasgt run' and Snakemake: the schema, then the stage sections' dataclasses.
WF_CONFIG = wf_config.check_config(wf_config.validate_schema(config, config_file=_config_file()), _config_file())
SEQUENCES = WF_CONFIG.names
SIMULATED = [s.name for s in WF_CONFIG.select(sources=["simulate"])]


# Targets of rule all. Each stage's .smk registers its own with final_output(...).
FINAL_OUTPUTS = []


def final_output(stage, pattern, *, splits=None, sources=None):
    """Register targets of the 'all' rule for a stage.

    pattern: a path with {sequence} (expanded over the sequences, optionally only those of some
    splits / sources), a fixed path (e.g. a model), or a function(WF_CONFIG) -> list of paths.
    Example (in workflow/rules/recover.smk):
        final_output("recover", "results/recover/{sequence}/bias.parquet")
    """
    FINAL_OUTPUTS.append(
        wf.FinalOutput(
            stage,
            pattern,
            None if splits is None else tuple(wf.Split(s) for s in splits),
            None if sources is None else tuple(wf.source_kind(s) for s in sources),
        )
    )


def get_final_outputs(wildcards=None):
    return wf.final_outputs(FINAL_OUTPUTS, WF_CONFIG)


def get_simulate_settings(wildcards):
    return wf.simulate_settings(WF_CONFIG, wildcards.sequence)


def get_simulate_input(wildcards):
    return wf.simulate_inputs(WF_CONFIG, wildcards.sequence, os.getcwd())


def get_ingest_input(wildcards):
    return wf.ingest_input(WF_CONFIG, wildcards.sequence, os.getcwd())


def get_ingest_extra_inputs(wildcards):
    return wf.ingest_extra_inputs(WF_CONFIG, wildcards.sequence, os.getcwd())


def get_ingest_settings(wildcards):
    return wf.ingest_settings(WF_CONFIG, wildcards.sequence)


def get_recovery_settings(wildcards):
    return wf.recovery_settings(WF_CONFIG, wildcards.sequence)


def get_interpolation_settings(wildcards):
    return wf.interpolation_settings(WF_CONFIG, wildcards.sequence)


def get_validation_settings(wildcards):
    return wf.validation_settings(WF_CONFIG, wildcards.sequence)


def get_validation_bias_inputs(wildcards):
    return wf.validation_bias_inputs(WF_CONFIG, wildcards.sequence, os.getcwd())


def get_windows_inputs(wildcards):
    return wf.windows_inputs(WF_CONFIG)


def get_windows_settings(wildcards):
    return wf.windows_settings(WF_CONFIG)
