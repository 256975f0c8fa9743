# Stage training_report: the training report (results/report/training.html): Table I, training
# curves, predicted vs ground-truth bias on test windows, calibration, parameters and latency.


rule training_report:
    input:
        evaluations=learning.evaluation_summaries(TRAINING_PLAN, EVALUATION),
        runs=[learning.training_run_dir(m, s) for m, s in TRAINING_PLAN.runs()],
    output:
        report(
            learning.TRAINING_REPORT,
            caption="../report/training.rst",
            category="Training report",
        ),
    log:
        wf.log_file("report", "training"),
    threads: 1
    script:
        "../scripts/training_report.py"
