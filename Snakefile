# biasgt workflow: IMU + pose recordings -> checked canonical stores -> ground-truth bias -> ...
#
#   biasgt run [--config FILE] [--cores N]              (recommended; see 'biasgt run --help')
#   snakemake --cores N --configfile FILE               (from a folder holding results/ and logs/)
#   biasgt run --profile slurm                          (SLURM: workflow/profiles/slurm, docs/cluster.md)
#
# Outputs: results/<stage>/<sequence>/..., logs: logs/<stage>/<sequence>.log (<stage>: simulate,
# ingest, recovery, interpolation, validation, windows (one 'dataset'), training and evaluation
# (results/{training,evaluation}/{method}/...; Table I in results/evaluation/table.md), report (one page per
# sequence and results/report/index.html over all of them).
# A stage is one .smk file under workflow/rules/: add it with one 'include:' line below; it
# registers its final outputs with final_output(...) (see workflow/rules/common.smk).

from snakemake.utils import min_version

min_version("9.0")


# The default config applies only when no --configfile is given: a given config replaces it
# entirely (also in cluster jobs, which receive the same --configfiles but not
# --replace-workflow-config).
if not workflow.overwrite_configfiles:

    configfile: "config/config.yaml"


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"


wildcard_constraints:
    sequence=wf.names_regex(SEQUENCES),


localrules:
    all,


rule all:
    input:
        get_final_outputs,
    default_target: True


include: "workflow/rules/simulate.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/recover.smk"
include: "workflow/rules/interpolate.smk"
include: "workflow/rules/validate.smk"
include: "workflow/rules/windows.smk"
include: "workflow/rules/train.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/table.smk"
include: "workflow/rules/training_report.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/dataset_report.smk"
