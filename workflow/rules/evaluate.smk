# Stage evaluate: PRMSE / ROE on the test split's non-overlapping 1-s windows (training.evaluation.evaluate):
# results/evaluation/{method}/seed{seed}/ for each trained run and results/evaluation/{reference}/
# for the rows that need no training (training/references.py).
# params: the 'evaluation:' section without 'references' (samples, samplers, steps, seed, ...).


rule evaluate:
    input:
        dataset=windows_dataset_input,
        run=learning.training_run_dir("{method}", "{seed}"),
    output:
        directory(learning.evaluation_dir("{method}", "{seed}")),
    log:
        wf.log_file("evaluate", "{method}_seed{seed}"),
    params:
        # a regression model draws no samples: the sampling options rerun only the diffusion models'
        settings=lambda wildcards: learning.evaluation_settings(
            WF_CONFIG.section("evaluation"), sampled=learning.is_sampled(wildcards.method)
        ),
        dataset_checksum=windows_dataset_checksum,
    threads: TRAINING_PLAN.threads
    priority: lambda wildcards: learning.chain_priority(wildcards.method)  # as the rule train
    script:
        "../scripts/evaluate.py"


rule evaluate_reference:
    input:
        dataset=windows_dataset_input,
    output:
        directory(learning.evaluation_dir("{reference}")),
    log:
        wf.log_file("evaluate", "{reference}"),
    params:
        settings=learning.evaluation_settings(WF_CONFIG.section("evaluation"), sampled=False),
        dataset_checksum=windows_dataset_checksum,
    threads: 1
    script:
        "../scripts/evaluate.py"
