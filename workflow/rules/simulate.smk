# Stage simulate: SimConfig (from a 'source: simulate' entry) -> results/simulate/{sequence}/,
# an ASL/EuRoC-style mav0 folder that rule ingest reads like a real recording.


rule simulate:
    input:
        get_simulate_input,
    output:
        report(
            directory("results/simulate/{sequence}"),
            patterns=["{name,[^/]+}.yaml"],
            caption="../report/simulate.rst",
            category="Simulate",
            labels={"sequence": "{sequence}", "file": "{name}.yaml"},
        ),
    log:
        "logs/simulate/{sequence}.log",
    params:
        settings=get_simulate_settings,
    wildcard_constraints:
        sequence=wf.names_regex(SIMULATED),
    threads: 1
    script:
        "../scripts/simulate.py"
