# Stage windows: one window dataset of every sequence whose split is train, val or test:
# results/windows/dataset/ (manifest.json + arrays, see training/data/windows.py).
# params: the 'windows:' section and the (name, split) list, so that a changed split or window
# option reruns this job only.
# A checkpoint: the learning jobs depend on the dataset's content (checksum), read after it is written
# (windows_dataset_input / windows_dataset_checksum), so that a dataset rewritten unchanged (say, after a
# verdict threshold changed no verdict) retrains and re-evaluates nothing.


checkpoint windows:
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


def windows_dataset_input(wildcards):
    """The window dataset as a learning job's input: ancient (its time stamp alone reruns nothing)."""
    return ancient(checkpoints.windows.get().output[0])


def windows_dataset_checksum(wildcards):
    """The dataset's content checksum (biasgt.workflow.learning.dataset_checksum): a learning job's parameter."""
    from biasgt.workflow.learning import dataset_checksum

    return dataset_checksum(wf.windows_dataset_dir())
