# Stage table: Table I from every evaluation (results/evaluation/table.csv and table.md); built
# when the window dataset has a train and a test sequence.


rule table:
    input:
        evaluations=learning.evaluation_summaries(TRAINING_PLAN, EVALUATION),
    output:
        learning.table_outputs(),
    log:
        learning.TABLE_LOG,
    threads: 1
    script:
        "../scripts/table.py"


final_output("table", lambda cfg: learning.learning_outputs(cfg, wf))
