# Stage dataset_report: one page over every sequence (results/report/index.html): verdicts, windows per
# split and what was left out, a sortable row per sequence linking its quality report, Table I's
# averages (when the learning stages run) and every sequence's recovered bias in one figure.


def get_dataset_report_inputs(wildcards):
    return {**wf.dataset_report_inputs(WF_CONFIG), "learning": learning.learning_outputs(WF_CONFIG, wf)}


rule dataset_report:
    input:
        unpack(get_dataset_report_inputs),
    output:
        report(
            wf.dataset_report_path(),
            caption="../report/dataset_report.rst",
            category="Dataset report",
        ),
    log:
        wf.log_file("report", "dataset"),
    params:
        settings=lambda wildcards: wf.dataset_report_settings(WF_CONFIG),
        results=wf.RESULTS_DIR,
    threads: 1
    script:
        "../scripts/dataset_report.py"


final_output("dataset_report", wf.dataset_report_path())
