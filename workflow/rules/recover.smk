# Stage recover: canonical store -> ground-truth IMU bias by joint optimisation (GTSAM):
# results/recovery/{sequence}/ (bias.csv, recovery.json, trajectory_tum.txt).
# params: the 'recovery:' section merged with the entry's own 'recovery:' (pose_stream + options),
# so that changing it reruns this job and its dependents only.


rule recover:
    input:
        store=wf.stage_dir("ingest", "{sequence}"),
    output:
        report(
            directory(wf.stage_dir("recover", "{sequence}")),
            patterns=["{name,recovery}.json"],
            caption="../report/recover.rst",
            category="Recovery",
            labels={"sequence": "{sequence}", "file": "{name}.json"},
        ),
    log:
        wf.log_file("recover", "{sequence}"),
    params:
        settings=get_recovery_settings,
    threads: 1
    script:
        "../scripts/recover.py"


final_output("recover", wf.stage_dir("recover", "{sequence}"))
