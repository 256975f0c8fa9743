"""Refusals of the learning commands: each is one error line naming the culprit and the fix, exit 2, no
traceback and no output left behind (a test split the model saw, another IMU rate, a full disk, a
run folder in use by another training)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from biasgt.cli.app import main
from training.data.windows import WindowConfig, WindowSource, build_window_dataset
from window_data import make_window_dataset, train_tiny


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A tiny 200-Hz window dataset (train0 / val0 / test0) and a regression run trained on it."""
    root = tmp_path_factory.mktemp("refusals")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    train_tiny(data, root / "run", "regression_rnn")
    return root


def _first_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1, err
    return lines[0]


def test_evaluate_refuses_a_test_split_holding_a_sequence_the_model_trained_on(trained, tmp_path, capsys):
    """A dataset whose test split holds train0 (the model's train sequence): refused naming it; the
    explicit flag evaluates it anyway."""
    src = [WindowSource("val0", "train", trained / "stores" / "val0", trained / "rec" / "val0"),
           WindowSource("train0", "test", trained / "stores" / "train0", trained / "rec" / "train0")]
    build_window_dataset(src, tmp_path / "leaked", WindowConfig(window_s=1.0, overlap=0.5))
    argv = ["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(tmp_path / "leaked"),
            "--out", str(tmp_path / "ev")]
    assert main(argv) == 2
    line = _first_error(capsys)
    assert line.startswith(f"biasgt evaluate: error: {trained / 'run' / 'best.pt'}: the test split of "
                           f"{tmp_path / 'leaked'} holds 1 sequence(s) the model trained on: train0"), line
    assert "--allow-train-overlap" in line and not (tmp_path / "ev").exists()
    assert main([*argv, "--allow-train-overlap"]) == 0
    assert (tmp_path / "ev" / "summary.json").is_file()


def test_evaluate_on_another_rate_names_the_rate(trained, tmp_path, capsys):
    """A 200-Hz model on a real 100-Hz dataset (whose 1-s windows have 101 samples, not 201): the rate is named."""
    slow = make_window_dataset(tmp_path, splits={"train": 1, "test": 1}, duration_s=5.0, rate_hz=100.0)
    assert main(["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(slow),
                 "--out", str(tmp_path / "ev")]) == 2
    line = _first_error(capsys)
    assert line.startswith(f"biasgt evaluate: error: {slow}: IMU rate 100 Hz, the checkpoint was trained at "
                           "200 Hz; re-create the dataset with --resample-hz 200"), line
    assert not (tmp_path / "ev").exists()


# ----------------------------------------------------------------------------- full disk, a folder in use

#: What numpy's np.save and torch.save raise on a full disk: a write cut short, no errno.
NUMPY_SHORT_WRITE = OSError("10854 requested and 2032 written")
TORCH_SHORT_WRITE = RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 606720 vs 606608")


def _seq_args(root: Path, *names_splits: tuple[str, str]) -> list[str]:
    args = []
    for name, split in names_splits:
        args += ["--seq", name, split, str(root / "stores" / name), str(root / "rec" / name)]
    return [*args, "--allow-unvalidated"]


@pytest.mark.parametrize("where", ["arrays", "records"])
def test_windows_on_a_full_disk_is_one_line_and_leaves_nothing(trained, tmp_path, capsys, monkeypatch, where):
    """np.save cut short (as numpy says it: no errno) while writing the window arrays, or later the sequence
    records: one line naming the folder, and neither the dataset nor a temporary folder is left."""
    import numpy as np

    save = np.save

    def full(path, *args, **kwargs):
        if where == "arrays" or Path(path).parent.parent.name.startswith(".context."):
            raise NUMPY_SHORT_WRITE
        return save(path, *args, **kwargs)

    monkeypatch.setattr(np, "save", full)
    out = tmp_path / "out" / "ds"
    rc = main(["windows", *_seq_args(trained, ("train0", "train"), ("val0", "val")), "--out", str(out)])
    assert rc == 2
    assert _first_error(capsys) == (f"biasgt windows: error: {out}: cannot write the output: no space left on device "
                                    f"in folder {out.parent} (nothing was written); free some space there (or raise "
                                    "the quota), or choose another --out")
    assert list((tmp_path / "out").iterdir()) == []


def test_train_on_a_full_disk_is_one_line_and_leaves_no_run_folder(trained, tmp_path, capsys, monkeypatch):
    """torch.save cut short (torch's RuntimeError, no errno): one line, and the new run folder is gone."""
    import torch

    def full(*args, **kwargs):
        raise TORCH_SHORT_WRITE

    monkeypatch.setattr(torch, "save", full)
    out = tmp_path / "run"
    rc = main(["train", "--dataset", str(trained / "dataset"), "--method", "regression_rnn", "--preset", "tiny",
               "--max-steps", "2", "--threads", "1", "--out", str(out)])
    assert rc == 2
    line = _first_error(capsys)
    assert line.startswith(f"biasgt train: error: {out}{os.sep}") and \
        f"cannot write the output: no space left on device in folder {out} (nothing was written)" in line, line
    assert not out.exists()


def test_a_second_training_into_the_same_folder_is_refused(trained, tmp_path, capsys):
    """While a training holds the run folder, a second one into it refuses at once; the first one's folder is
    untouched (here the hold is the first training's own, training.fit.run_folder)."""
    from training.fit.run_folder import hold_run_folder

    out = tmp_path / "run"
    argv = ["train", "--dataset", str(trained / "dataset"), "--method", "regression_rnn", "--preset", "tiny",
            "--max-steps", "2", "--threads", "1", "--out", str(out)]
    with hold_run_folder(out):
        (out / "metrics.csv").write_text("step\n")  # the first training's file
        assert main(argv) == 2
        assert _first_error(capsys) == (f"biasgt train: error: {out}: the run folder is in use: another training "
                                        "writes there now; wait for it to finish, or choose another --out")
        assert [p.name for p in out.iterdir()] == ["metrics.csv"]
    (out / "metrics.csv").unlink()
    assert main(argv) == 0 and (out / "run.json").is_file()  # once free, the folder is trained into


def test_torchscript_export_on_a_full_disk_is_one_line_not_an_abort(trained, tmp_path, capsys, monkeypatch):
    """torch's own file writer aborts the process when the disk fills (rc 134, a temporary file left); the
    export is saved to memory and written by Python, whose ENOSPC is the one line and leaves nothing."""
    import errno

    write_bytes = Path.write_bytes

    def full(self, data):
        if self.name.startswith(".m.pt."):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    out = tmp_path / "x" / "m.pt"
    assert main(["export", "--checkpoint", str(trained / "run"), "--format", "torchscript", "--out", str(out)]) == 2
    assert _first_error(capsys).startswith(f"biasgt export: error: {out}: cannot write the output: no space left on "
                                           f"device in folder {out.parent} (nothing was written)")
    assert list(out.parent.iterdir()) == []
