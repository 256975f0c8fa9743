# Stage validate: 1-s integration error of the recovered bias against the reference (ground-truth
# state, else a pose stream): results/validation/{sequence}/ (validation.json, windows.parquet).
# A FAIL verdict is data (written and reported, the workflow goes on); bad inputs stop it.
# params: the 'validation:' section merged with the entry's own 'validation:' (poses, other bias files
# compared with the recovered one, options).


rule validate:
    input:
        store=wf.stage_dir("ingest", "{sequence}"),
        recovery=wf.stage_dir("recover", "{sequence}"),
        bias=get_validation_bias_inputs,
    output:
        report(
            directory(wf.stage_dir("validate", "{sequence}")),
            patterns=["{name,validation}.json"],
            caption="../report/validate.rst",
            category="Validation",
            labels={"sequence": "{sequence}", "file": "{name}.json"},
        ),
    log:
        wf.log_file("validate", "{sequence}"),
    params:
        settings=get_validation_settings,
    threads: 1
    script:
        "../scripts/validate.py"


final_output("validate", wf.stage_dir("validate", "{sequence}"))
