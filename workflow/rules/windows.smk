# Stage windows: one window dataset of every sequence whose split is train, val or test:
# results/windows/dataset/ (manifest.json + arrays, see training/windows.py).
# params: the 'windows:' section and the (name, split) list, so that a changed split or window
# option reruns this job only.


rule windows:
    input:
        unpack(get_windows_inputs),
    output:
        report(
            directory(wf.windows_dataset_dir()),
            patterns=["{name,manifest}.json"],
            caption="../report/windows.rst",
            category="Windows",
            labels={"file": "{name}.json"},
        ),
    log:
        wf.log_file("windows", wf.WINDOWS_DATASET),
    params:
        settings=get_windows_settings,
    threads: 1
    script:
        "../scripts/windows.py"


final_output("windows", wf.window_outputs)
