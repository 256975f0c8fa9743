# Stage train: one job per learned method and seed of the 'training:' section (training.config.
# TrainingPlan): results/training/{method}/seed{seed}/ ('biasgt train': best.pt chosen on the
# validation split, last.pt, metrics.csv, run.json), from the window dataset.
# params: the run's resolved TrainConfig, so that a changed option retrains, and adding a method
# or a seed trains only the new runs.

from biasgt.workflow import learning

TRAINING_PLAN = learning.TrainingPlan.from_mapping(WF_CONFIG.section("training"))
EVALUATION = learning.EvaluationConfig.from_mapping(WF_CONFIG.section("evaluation"))


wildcard_constraints:
    method=wf.names_regex(learning.network_names()),
    seed=r"\d+",
    reference=wf.names_regex(learning.reference_names()),


rule train:
    input:
        dataset=windows_dataset_input,
    output:
        directory(learning.training_run_dir("{method}", "{seed}")),
    log:
        wf.log_file("train", "{method}_seed{seed}"),
    params:
        config=lambda wildcards: TRAINING_PLAN.run_settings(wildcards.method, wildcards.seed),
        dataset_checksum=windows_dataset_checksum,
        processes=TRAINING_PLAN.processes,
    threads: TRAINING_PLAN.threads
    # the sampled (diffusion) models' chains are the longest (their evaluation draws K samples per
    # window): started first, they leave the short jobs to fill the cores at the end
    priority: lambda wildcards: learning.chain_priority(wildcards.method)
    script:
        "../scripts/train.py"
