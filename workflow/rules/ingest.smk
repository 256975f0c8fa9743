# Stage ingest: any source -> checked canonical store results/ingest/{sequence}/
# (sequence.yaml + Parquet tables, see pipeline/store.py).


rule ingest:
    input:
        source=get_ingest_input,
        extra_poses=get_ingest_extra_inputs,
    output:
        report(
            directory("results/ingest/{sequence}"),
            patterns=["{name,[^/]+}.yaml"],
            caption="../report/ingest.rst",
            category="Ingest",
            labels={"sequence": "{sequence}", "file": "{name}.yaml"},
        ),
    log:
        "logs/ingest/{sequence}.log",
    params:
        settings=get_ingest_settings,
    threads: 1
    script:
        "../scripts/ingest.py"


final_output("ingest", "results/ingest/{sequence}")
