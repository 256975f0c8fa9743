# Stage report: the dataset quality report of one sequence, one self-contained HTML file:
# results/report/{sequence}/report.html (what 'biasgt report results --sequence NAME' writes).


rule report:
    input:
        store=wf.stage_dir("ingest", "{sequence}"),
        recovery=wf.stage_dir("recover", "{sequence}"),
        validation=wf.stage_dir("validate", "{sequence}"),
    output:
        report(
            wf.report_path("{sequence}"),
            caption="../report/report.rst",
            category="Quality report",
            labels={"sequence": "{sequence}"},
        ),
    log:
        wf.log_file("report", "{sequence}"),
    threads: 1
    script:
        "../scripts/report.py"


final_output("report", wf.report_path("{sequence}"))
