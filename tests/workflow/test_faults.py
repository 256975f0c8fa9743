"""Fault suite of the learning commands and the workflow: each fault gives one error line naming the
culprit, a non-zero exit, no traceback and no output; never an exit 0 with wrong or non-finite results.

Faults: corrupted checkpoints (truncated, random bytes, bit-flipped, NaN weights, outputs that
overflow, an unfinished run folder), NaN/inf in each dataset array, recordings in the wrong units or
with unparseable lines, output paths of the wrong kind, SIGINT/SIGTERM to ``biasgt run`` (no orphan
process, checked with psutil) and during sampling, a second concurrent run, configs that drop jobs
or clamp options silently, and the messages of bad configs.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import psutil
import pytest
import torch
import yaml

from biasgt.cli.app import main
from pipeline.sim import ImuNoiseConfig, SimConfig, simulate
from pipeline.sim.writer import write_simulation
from training.fit.checkpoint import BEST, load_checkpoint, load_run, save_checkpoint
from training.data.dataset import ARRAYS
from window_data import make_window_dataset, train_tiny

pytestmark = pytest.mark.xdist_group("faults")

EVAL = ["--samples", "2", "--steps", "2"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A tiny window dataset, a diffusion run trained on it, and a 200-Hz ASL recording."""
    root = tmp_path_factory.mktemp("faults")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    train_tiny(data, root / "run", "diffusion_rnn")
    sim = simulate(SimConfig(duration_s=4.0, seed=21, name="rec", imu=ImuNoiseConfig(rate_hz=200.0)))
    write_simulation(sim, root / "rec")
    return root


def _run_cli(args: list[str], capsys) -> tuple[int, str]:
    rc = main(args)
    err = capsys.readouterr().err
    return rc, err


def _one_line_error(err: str, *words: str) -> None:
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], err


# ----------------------------------------------------------------------------- corrupted checkpoints


def _truncated(src: Path, dst: Path) -> None:
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])


def _random_bytes(src: Path, dst: Path) -> None:
    dst.write_bytes(np.random.default_rng(0).bytes(src.stat().st_size))


def _bit_flipped(src: Path, dst: Path) -> None:
    """Four 0xff bytes (a float32 NaN) in the middle of every stored tensor: the file still loads."""
    shutil.copy(src, dst)
    with zipfile.ZipFile(src) as z:
        records = [(i.header_offset, len(i.filename.encode()), i.file_size) for i in z.infolist()
                   if "/data/" in i.filename and i.file_size >= 16]
    raw = bytearray(dst.read_bytes())
    for header, name_len, size in records:
        extra_len = int.from_bytes(raw[header + 28:header + 30], "little")
        start = header + 30 + name_len + extra_len + (size // 2) // 4 * 4
        raw[start:start + 4] = b"\xff\xff\xff\xff"
    dst.write_bytes(bytes(raw))


CORRUPTIONS = {"truncated": _truncated, "random_bytes": _random_bytes, "bit_flipped": _bit_flipped}


@pytest.mark.parametrize("corruption", sorted(CORRUPTIONS))
@pytest.mark.parametrize("command", ["predict", "evaluate"])
def test_corrupted_checkpoint_is_refused_naming_it(trained, tmp_path, capsys, corruption, command):
    bad = tmp_path / "bad.pt"
    CORRUPTIONS[corruption](trained / "run" / BEST, bad)
    out = tmp_path / "out"
    if command == "predict":
        args = ["predict", str(trained / "rec"), "--checkpoint", str(bad), "--out", str(out), *EVAL]
    else:
        args = ["evaluate", "--checkpoint", str(bad), "--dataset", str(trained / "dataset"), "--out", str(out), *EVAL]
    rc, err = _run_cli(args, capsys)
    assert rc == 2
    _one_line_error(err, str(bad))
    assert not list(tmp_path.glob("out*"))


def test_bit_flipped_checkpoint_from_before_checksums_is_refused_as_non_finite(trained, tmp_path):
    """A checkpoint without stored checksums is still refused when a weight is NaN."""
    from training.fit.checkpoint import CheckpointError

    state = load_checkpoint(trained / "run" / BEST)
    state.pop("weights_sha256")
    name = next(k for k, v in state["ema"]["model"].items() if v.is_floating_point() and v.numel() > 4)
    state["ema"]["model"][name].view(-1)[0] = float("nan")
    torch.save(state, tmp_path / "old.pt")
    with pytest.raises(CheckpointError, match=f"weights '{name}' hold non-finite"):
        load_run(tmp_path / "old.pt")


def test_model_with_non_finite_output_is_refused_naming_the_checkpoint(trained, tmp_path, capsys):
    """Finite weights, consistent checksums, but outputs that overflow: predict and evaluate refuse them."""
    state = load_checkpoint(trained / "run" / BEST)
    for weights in (state["model"], state["ema"]["model"]):
        for key, value in weights.items():
            if value.is_floating_point() and "normalizer" not in key and value.dim() >= 1:
                weights[key] = torch.full_like(value, 1e30)
    save_checkpoint(state, tmp_path / "huge.pt")
    rc, err = _run_cli(["predict", str(trained / "rec"), "--checkpoint", str(tmp_path / "huge.pt"),
                        "--out", str(tmp_path / "p"), *EVAL], capsys)
    assert rc == 2
    _one_line_error(err, "non-finite", "huge.pt")
    assert not list(tmp_path.glob("p.*"))
    rc, err = _run_cli(["evaluate", "--checkpoint", str(tmp_path / "huge.pt"), "--dataset",
                        str(trained / "dataset"), "--out", str(tmp_path / "ev"), *EVAL], capsys)
    assert rc == 2
    _one_line_error(err, "non-finite", "huge.pt")
    assert not (tmp_path / "ev").exists()


# ----------------------------------------------------------------------------- wrong units into predict


def _rescaled_recording(src: Path, dst: Path, columns: slice, factor: float) -> Path:
    shutil.copytree(src, dst)
    csv = dst / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        fields = line.split(",")
        vals = [float(x) * factor for x in fields[columns]]
        fields[columns] = [f"{v:.9g}" for v in vals]
        out.append(",".join(fields))
    csv.write_text("\n".join(out) + "\n")
    return dst


@pytest.mark.parametrize(("case", "columns", "factor", "code"), [
    ("acc_in_g", slice(4, 7), 1.0 / 9.80665, "ACC_IN_G"),
    ("gyro_in_degps", slice(1, 4), 180.0 / np.pi, "GYRO_DEGPS"),
])
def test_predict_refuses_a_recording_in_wrong_units(trained, tmp_path, capsys, case, columns, factor, code):
    rec = _rescaled_recording(trained / "rec", tmp_path / case, columns, factor)
    rc, err = _run_cli(["predict", str(rec), "--checkpoint", str(trained / "run"), "--out", str(tmp_path / "p"),
                        *EVAL], capsys)
    assert rc == 2
    _one_line_error(err, code, "refusing to predict")
    assert not list(tmp_path.glob("p.*"))


def test_predict_on_a_good_recording_and_its_rate_hint(trained, tmp_path, capsys):
    rc, _ = _run_cli(["predict", str(trained / "rec"), "--checkpoint", str(trained / "run"),
                      "--out", str(tmp_path / "p"), *EVAL], capsys)
    assert rc == 0 and (tmp_path / "p.csv").is_file()
    sim = simulate(SimConfig(duration_s=4.0, seed=22, name="r100", imu=ImuNoiseConfig(rate_hz=100.0)))
    write_simulation(sim, tmp_path / "r100")
    rc, err = _run_cli(["predict", str(tmp_path / "r100"), "--checkpoint", str(trained / "run"),
                        "--out", str(tmp_path / "q"), *EVAL], capsys)
    assert rc == 2
    _one_line_error(err, "100 Hz", "resample")
    assert "biasgt windows" not in err  # windows resamples a dataset, not predict's input


# ----------------------------------------------------------------------------- outputs that are files


@pytest.mark.parametrize("command", ["evaluate", "train", "predict"])
def test_output_path_that_is_a_file_is_refused_before_any_work(trained, tmp_path, capsys, command, monkeypatch):
    import training.fit.checkpoint as checkpoint
    import training.fit.train as train_module

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the output location was checked")

    monkeypatch.setattr(checkpoint, "load_run", no_work)
    monkeypatch.setattr(train_module, "train", no_work)
    blocker = tmp_path / "taken"
    blocker.write_text("keep me")
    if command == "evaluate":
        args = ["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(trained / "dataset"),
                "--out", str(blocker), *EVAL]
    elif command == "train":
        args = ["train", "--dataset", str(trained / "dataset"), "--out", str(blocker), "--method", "regression_rnn"]
    else:
        (tmp_path / "taken.csv").mkdir()
        args = ["predict", str(trained / "rec"), "--checkpoint", str(trained / "run"), "--out", str(blocker), *EVAL]
    rc, err = _run_cli(args, capsys)
    assert rc == 2
    _one_line_error(err, "taken")
    assert blocker.read_text() == "keep me"


# ----------------------------------------------------------------------------- NaN / inf in the dataset


@pytest.mark.parametrize("array", [a for a in ARRAYS if a != "t_ns"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_dataset_array_is_named_when_opened(trained, tmp_path, capsys, array, value):
    data = tmp_path / "dataset"
    shutil.copytree(trained / "dataset", data)
    split = "val" if array in ("imu", "bias") else "test"  # train in one run, evaluate in the other
    path = data / "sequences" / f"{split}0" / f"{array}.npy"
    arr = np.load(path)
    arr[2].reshape(-1)[0] = value
    np.save(path, arr)
    if split == "val":
        out = tmp_path / "run"
        (tmp_path / "tiny.yaml").write_text("batch_size: 4\ndevice: cpu\nval_every: 1\nwarmup_steps: 1\nthreads: 1\n")
        args = ["train", "--dataset", str(data), "--out", str(out), "--method", "regression_rnn", "--preset", "tiny",
                "--max-steps", "2", "--config", str(tmp_path / "tiny.yaml")]
    else:
        out = tmp_path / "ev"
        args = ["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(data), "--out", str(out), *EVAL]
    rc, err = _run_cli(args, capsys)
    if array == "bias_std" and np.isnan(value):  # unknown std (a recovery without marginals): accepted
        assert rc == 0, err
        return
    assert rc == 2
    _one_line_error(err, f"{array}.npy", "window 2", "non-finite")
    assert not out.exists()


# ----------------------------------------------------------------------------- biasgt run under signals

REPO = Path(__file__).resolve().parents[2]


def _biasgt_run(workdir: Path, *extra: str, new_session: bool = False) -> subprocess.Popen:
    """``biasgt run`` (a 300-s simulated sequence, up to its recovery) as a separate process (the leader of
    its own process group with ``new_session``, as a shell's job is)."""
    cfg = workdir / "cfg.yaml"
    cfg.write_text(yaml.safe_dump({"sequences": [{"name": "long", "source": "simulate", "duration_s": 300,
                                                  "seed": 3}]}))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-m", "biasgt.cli", "run", "--config", str(cfg), "--directory",
                             str(workdir), "--cores", "1", "--target", "results/recovery/long", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=_foreground_sigint, start_new_session=new_session)


def _foreground_sigint() -> None:
    """SIGINT handled as in a foreground process (a background test runner's children inherit it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for_job(proc: subprocess.Popen, rule_script: str, timeout_s: float = 300.0) -> list[psutil.Process]:
    """Every descendant of ``proc`` once one of them runs the rule's script."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        family = psutil.Process(proc.pid).children(recursive=True)
        for p in family:
            with contextlib.suppress(psutil.Error):
                if any(rule_script in part for part in p.cmdline()):
                    return family
        time.sleep(0.5)
    raise AssertionError(f"no job running {rule_script} after {timeout_s} s")


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_to_biasgt_run_stops_snakemake_and_its_job(tmp_path, sig, code):
    proc = _biasgt_run(tmp_path)
    family = _wait_for_job(proc, ".recover.py")
    assert family, "snakemake and its job run as children of biasgt run"
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    gone, alive = psutil.wait_procs(family, timeout=5)
    assert alive == [], [p.cmdline() for p in alive]  # no orphan (re-parented to PID 1) left running
    assert not (tmp_path / "results" / "recovery" / "long").exists()  # incomplete output removed


def test_second_biasgt_run_in_the_same_folder_names_the_first(tmp_path, capsys):
    first = _biasgt_run(tmp_path)
    try:
        _wait_for_job(first, ".simulate.py")
        rc = main(["run", "--config", str(tmp_path / "cfg.yaml"), "--directory", str(tmp_path),
                   "--target", "results/recovery/long"])
        err = capsys.readouterr().err
        assert rc == 2
        _one_line_error(err, f"another 'biasgt run' (pid {first.pid})")
        assert "--unlock" not in err
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=120)


def test_kill_9_of_the_biasgt_run_group_stops_snakemake_and_its_job(tmp_path, capsys):
    """``kill -9`` of the ``biasgt run`` process group: Snakemake (in its own session) and its job stop by
    themselves, remove the incomplete output and their lock; ``-- --unlock`` then says it ran nothing."""
    proc = _biasgt_run(tmp_path, new_session=True)
    try:
        family = _wait_for_job(proc, ".simulate.py")
        assert any("guarded_snakemake" in " ".join(p.cmdline()) for p in family)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=30)
        gone, alive = psutil.wait_procs(family, timeout=60)
        assert alive == [], [p.cmdline() for p in alive]  # nothing left running without its parent
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert not (tmp_path / "results" / "simulate" / "long").exists()  # incomplete output removed
    locks = tmp_path / ".snakemake" / "locks"
    assert not locks.exists() or list(locks.iterdir()) == []
    rc = main(["run", "--config", str(tmp_path / "cfg.yaml"), "--directory", str(tmp_path), "--", "--unlock"])
    out = capsys.readouterr().out
    assert rc == 0 and out.startswith(f"unlocked {tmp_path}") and "nothing was run" in out
    assert "results:" not in out and "Table I" not in out  # never reads as a finished run


def test_a_live_snakemake_of_an_earlier_run_is_named_and_a_stale_lock_cleared(tmp_path, capsys, caplog,
                                                                               monkeypatch):
    """A job of an earlier run still running in the folder: the rerun and --unlock name it (pid, script);
    once it is gone, a Snakemake lock left behind (Snakemake itself killed) is cleared by the rerun."""
    import biasgt.workflow.run as workflow_run

    monkeypatch.setattr(workflow_run, "ORPHAN_WAIT_S", 0.5)
    script = tmp_path / ".snakemake" / "scripts" / "tmpab12.recover.py"
    job = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)", str(script)])
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"sequences": [{"name": "s", "source": "simulate", "duration_s": 3, "seed": 1}]}))
    run = ["run", "--config", str(cfg), "--directory", str(tmp_path), "--until", "simulate"]
    try:
        for argv in (run, ["run", "--config", str(cfg), "--directory", str(tmp_path), "--unlock"]):
            rc, err = _run_cli(argv, capsys)
            assert rc == 2
            _one_line_error(err, "still works in", f"pid {job.pid} (recover.py)", f"kill -INT {job.pid}")
    finally:
        job.kill()
        job.wait()
    locks = tmp_path / ".snakemake" / "locks"
    locks.mkdir(parents=True)
    (locks / "0.output.lock").write_text(str(tmp_path / "results" / "simulate" / "s") + "\n")
    caplog.set_level("WARNING")
    rc, err = _run_cli([*run, "--", "--list-rules"], capsys)  # a rerun that runs no job: quick
    assert rc == 0, err
    assert any("clearing the Snakemake lock a killed run left" in r.getMessage() for r in caplog.records)
    assert not locks.exists() or list(locks.iterdir()) == []


def test_a_run_in_another_folder_of_the_same_checkout_does_not_count(tmp_path, capsys, monkeypatch):
    """A Snakemake working in another --directory (same Snakefile, same checkout, started from here) is not
    an earlier run of this folder; one in this folder whose 'biasgt run' lives is named with that parent."""
    import biasgt.workflow.run as workflow_run

    monkeypatch.setattr(workflow_run, "ORPHAN_WAIT_S", 0.5)
    here, other = tmp_path / "checkout", tmp_path / "checkout" / "runs" / "b"
    other.mkdir(parents=True)
    sleeper = [sys.executable, "-c", "import time; time.sleep(120)"]
    snakefile = ["--snakefile", str(here / "Snakefile")]
    elsewhere = subprocess.Popen([*sleeper, "-m", "snakemake", *snakefile, "--directory", str(other)], cwd=here)
    try:
        workflow_run.check_no_earlier_run(here, wait_s=0.0)  # not refused: it works in runs/b
        served = subprocess.Popen([*sleeper, "-m", "biasgt.workflow.guarded_snakemake", str(os.getpid()), *snakefile,
                                   "--directory", str(here)], cwd=other)
        try:
            rc, err = _run_cli(["run", "--directory", str(here), "--until", "simulate"], capsys)
            assert rc == 2
            _one_line_error(err, f"biasgt run: error: an earlier run's Snakemake still works in {here} for the live "
                                 f"'biasgt run' pid {os.getpid()}: pid {served.pid} (snakemake)")
            assert str(elsewhere.pid) not in err
        finally:
            served.kill()
            served.wait()
    finally:
        elsewhere.kill()
        elsewhere.wait()


@pytest.mark.parametrize("code", ["EROFS", "ENOSPC"])
def test_run_in_a_read_only_or_full_folder_is_one_line(tmp_path, capsys, monkeypatch, code):
    """``biasgt run --directory`` (and ``--unlock``) where nothing can be written (EROFS, as a read-only mount
    says it; ENOSPC, a full disk): one line naming the folder, exit 2."""
    import errno
    import tempfile

    import biasgt.workflow.run as workflow_run

    number = getattr(errno, code)

    def refused(*args, **kwargs):
        raise OSError(number, os.strerror(number))

    monkeypatch.setattr(tempfile, "mkstemp", refused)
    first = (f"biasgt run: error: cannot write in the working directory {tmp_path} (Read-only file system); choose "
             "a writable --directory" if code == "EROFS" else
             f"biasgt run: error: {tmp_path / 'results'}: cannot write the output: no space left on device in folder "
             f"{tmp_path} (nothing was written)")
    for extra in (["--until", "simulate"], ["--unlock"]):
        rc, err = _run_cli(["run", "--directory", str(tmp_path), *extra], capsys)
        assert rc == 2
        _one_line_error(err, first)
    assert not (tmp_path / workflow_run.RUN_LOCK).exists()


# ----------------------------------------------------------------------------- other tracebacks


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def test_inspect_into_a_closed_pipe_is_no_traceback(trained):
    """``biasgt inspect SEQ | true``: the reader went away; not an error of ours."""
    proc = subprocess.Popen([sys.executable, "-m", "biasgt.cli", "inspect", str(trained / "rec")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env())
    proc.stdout.close()  # as 'true' does, before the report is written
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "BrokenPipeError" not in err, err


def test_gtsam_elimination_tree_error_is_a_one_line_recovery_error(trained, tmp_path, capsys, monkeypatch):
    """A ValueError from GTSAM's EliminationTree (a solve on deg/s data read as rad/s) is a known error,
    and the hint names the ignored unit finding."""
    import recovery.recover as rec

    def broken(*args, **kwargs):
        raise ValueError("EliminationTree: given ordering contains variables that are not involved in the graph")

    monkeypatch.setattr(rec, "_recover", broken)
    degps = _rescaled_recording(trained / "rec", tmp_path / "degps", slice(1, 4), 180.0 / np.pi)
    rc, err = _run_cli(["recover", str(degps), "--ignore", "GYRO_DEGPS", "--out", str(tmp_path / "r")], capsys)
    assert rc == 2
    _one_line_error(err, "EliminationTree", "GYRO_DEGPS were ignored", "--repair gyro-deg-to-rad")
    assert not (tmp_path / "r").exists()


# ----------------------------------------------------------------------------- skipped input lines


def test_skipped_lines_are_a_warning_of_every_reading_command_and_kept_in_the_stage_json(trained, tmp_path,
                                                                                         capsys, caplog):
    rec = tmp_path / "rec"
    shutil.copytree(trained / "rec", rec)
    csv = rec / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[99] = lines[99].split(",")[0] + ",abc,1,2,3,4,5"  # text in a number, line 100
    csv.write_text("\n".join(lines) + "\n" + lines[5].split(",")[0] + "9,1.0,2\n")  # truncated last line
    expected = "skipped 2 unparseable line(s) of imu0/data.csv (line 100, "
    runs = {
        "convert": ["convert", str(rec), "--out", str(tmp_path / "store")],
        "recover": ["recover", str(rec), "--out", str(tmp_path / "recovery")],
        "validate": ["validate", str(rec), "--recovery", str(tmp_path / "recovery"), "--out", str(tmp_path / "val")],
        "interpolate": ["interpolate", str(tmp_path / "recovery"), "--imu", str(rec),
                        "--out", str(tmp_path / "bias.parquet")],
        "predict": ["predict", str(rec), "--checkpoint", str(trained / "run"), "--out", str(tmp_path / "p"), *EVAL],
    }
    for name, args in runs.items():
        caplog.clear()
        rc = main(args)
        assert rc == 0, (name, capsys.readouterr().err)
        assert any(r.levelname == "WARNING" and expected in r.getMessage() for r in caplog.records), name
    recovery = json.loads((tmp_path / "recovery" / "recovery.json").read_text())
    assert any(expected in w for w in recovery["warnings"])
    validation = json.loads((tmp_path / "val" / "validation.json").read_text())
    assert any(expected in n for n in validation["notes"])


# ----------------------------------------------------------------------------- silent acceptance in configs


def test_config_without_a_test_split_says_so_once_at_config_check(tmp_path, caplog):
    import io

    from biasgt.workflow.config import config_warnings, load_config
    from biasgt.workflow.run import run_workflow

    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump({"sequences": [
        {"name": "a", "source": "simulate", "duration_s": 3, "seed": 1, "split": "train"},
        {"name": "b", "source": "simulate", "duration_s": 3, "seed": 2, "split": "val"}]}))
    caplog.set_level("WARNING")
    run_workflow(config_file=cfg, workdir=tmp_path, dry_run=True, echo=io.StringIO())
    said = [r.getMessage() for r in caplog.records if "split 'test'" in r.getMessage()]
    assert len(said) == 1 and "no model is trained or evaluated" in said[0], said
    assert said[0] == f"{cfg}: {config_warnings(load_config(cfg))[0]}"


def test_batch_size_larger_than_the_train_split_is_said_and_recorded(trained, tmp_path, caplog):
    """The train split has 9 windows; batch size 64 uses all 9 per step: said, and run.json records 9."""
    from training.data.dataset import WindowDataset

    n_train = len(WindowDataset(trained / "dataset", "train"))
    assert n_train < 64
    (tmp_path / "big.yaml").write_text("batch_size: 64\ndevice: cpu\nval_every: 1\nwarmup_steps: 1\nthreads: 1\n")
    caplog.set_level("WARNING")
    assert main(["train", "--dataset", str(trained / "dataset"), "--out", str(tmp_path / "run"), "--method",
                 "regression_rnn", "--preset", "tiny", "--max-steps", "1", "--config", str(tmp_path / "big.yaml")]) == 0
    assert any(f"batch_size 64 is larger than the train split ({n_train} windows)" in r.getMessage()
               for r in caplog.records)
    summary = json.loads((tmp_path / "run" / "run.json").read_text())
    assert summary["effective_batch_size"] == n_train and summary["config"]["batch_size"] == 64


# ----------------------------------------------------------------------------- messages


@pytest.mark.parametrize(("extra", "words"), [
    ({"training": {"options": {"bacth_size": 4}}},
     ["unknown key 'bacth_size' (did you mean 'batch_size'?)", "(field 'training.options')"]),
    ({"training": {"options": {"batch_size": -1}}}, ["(field 'training.options.batch_size')"]),
    ({"sequences": [{"name": "a", "source": "simulate", "splt": "train"}]},
     ["sequences[0] (sequence 'a')", "unknown key 'splt' (did you mean 'split'?)"]),
])
def test_config_errors_name_the_field_once_and_suggest_the_key(tmp_path, capsys, extra, words):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump({"sequences": [{"name": "a", "source": "simulate"}], **extra}))
    rc, err = _run_cli(["run", "--config", str(cfg), "--directory", str(tmp_path), "--dry-run"], capsys)
    assert rc == 2
    _one_line_error(err, *words)
    assert "training.training" not in err


#: A config with 16 errors of every kind: the schema's, the readers', the entries' and the sections' own.
SIXTEEN = """\
sequences:
  - {name: a, source: simulate, duration_s: -3, seed: 1, split: train}
  - {name: a, source: simulate, duration_s: 3, seed: 2, split: val}
  - {name: "bad name!", source: simulate, duration_s: 3, seed: 3}
  - {name: c, source: asl, path: missing/dir, split: test}
  - {name: d, source: nosuch, path: x}
  - {name: e, source: simulate, duration_s: 3, seed: 1, splitt: test}
training: {seeds: [2.9, -1], preset: huge, threads: a}
evaluation: {samplers: [nope]}
windows: {window_s: x}
recovery: {keyframe_rate_hz: x}
validation: {margin: [1]}
interpolation: {method: nope}
ingest: {gap_factr: 3}
trainng: {}
"""


def test_a_config_with_sixteen_errors_lists_every_one_in_one_pass(tmp_path, capsys):
    """Every error at once (one line, numbered), the seeds among them as non-negative integers; then with
    ``seeds: [x]`` alone, the seeds' own words, never Python's ``int()``."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(SIXTEEN)
    rc, err = _run_cli(["run", "--config", str(cfg), "--directory", str(tmp_path), "--dry-run"], capsys)
    assert rc == 2
    _one_line_error(err, f"biasgt run: error: {cfg}: 16 problems: [1] sequences[4].source (sequence 'd'): 'nosuch'")
    for words in ("unknown key 'trainng'", "unknown key 'gap_factr'", "sequences[0].duration_s", "is not a valid name",
                  "unknown key 'splitt'", "duplicate sequence name 'a'", "missing/dir does not exist",
                  "'recovery.keyframe_rate_hz'", "'interpolation.method'", "'validation.margin'", "'windows.window_s'",
                  "training seeds must be non-negative integers, got 2.9, -1", "'training.preset'",
                  "'training.threads'", "'nope' is not a valid Sampler"):
        assert err.count(words) == 1, words
    cfg.write_text(yaml.safe_dump({"sequences": [{"name": "a", "source": "simulate"}], "training": {"seeds": ["x"]}}))
    rc, err = _run_cli(["run", "--config", str(cfg), "--directory", str(tmp_path), "--dry-run"], capsys)
    assert rc == 2
    _one_line_error(err, f"biasgt run: error: {cfg}: training seeds must be non-negative integers, got 'x' (field "
                         "'training.seeds'); list whole numbers")
    assert "int()" not in err


# ----------------------------------------------------------------------------- interruptible sampling


@pytest.mark.parametrize(("command", "sig", "code"),
                         [("evaluate", signal.SIGTERM, 143), ("predict", signal.SIGINT, 130)])
def test_sampling_is_interruptible(trained, tmp_path, command, sig, code):
    """A signal during diffusion sampling (many samples and steps: minutes of work) ends the command
    at once with its exit code, and leaves no output."""
    out = tmp_path / "out"
    slow = ["--samples", "400", "--steps", "200"]
    if command == "evaluate":
        args = ["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(trained / "dataset"),
                "--out", str(out), *slow]
    else:
        args = ["predict", str(trained / "rec"), "--checkpoint", str(trained / "run"), "--out", str(out), *slow]
    proc = subprocess.Popen([sys.executable, "-m", "biasgt.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env(), preexec_fn=_foreground_sigint)
    try:
        for line in proc.stderr:
            if "sampling" in line:
                break
        time.sleep(1.0)
        assert proc.poll() is None, "finished before the signal: make the sampling longer"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert not list(tmp_path.glob("out*")) and not list(tmp_path.glob(".out*"))


def test_unfinished_run_folder_is_not_used_as_a_trained_model(trained, tmp_path, capsys):
    """A run folder whose training stopped (no run.json) does not look usable: evaluate and predict say so."""
    run = tmp_path / "run"
    shutil.copytree(trained / "run", run)
    (run / "run.json").unlink()
    for args in (["evaluate", "--checkpoint", str(run), "--dataset", str(trained / "dataset"), "--out",
                  str(tmp_path / "ev"), *EVAL],
                 ["predict", str(trained / "rec"), "--checkpoint", str(run), "--out", str(tmp_path / "p"), *EVAL]):
        rc, err = _run_cli(args, capsys)
        assert rc == 2
        _one_line_error(err, "did not finish", "--resume")
    assert not (tmp_path / "ev").exists() and not list(tmp_path.glob("p.*"))
    assert main(["predict", str(trained / "rec"), "--checkpoint", str(run / "best.pt"), "--out",
                 str(tmp_path / "p"), *EVAL]) == 0  # a file named directly is used


def test_non_finite_loss_before_any_checkpoint_claims_no_kept_checkpoint(trained, tmp_path, capsys, monkeypatch):
    """A diverged training with nothing saved yet says so, and names no folder as if it held a run."""
    from training.models.bias_model import BiasModel

    monkeypatch.setattr(BiasModel, "loss", lambda self, *a, **k: torch.tensor(float("nan"), requires_grad=True))
    (tmp_path / "tiny.yaml").write_text("batch_size: 4\ndevice: cpu\nval_every: 1\nwarmup_steps: 1\nthreads: 1\n")
    rc, err = _run_cli(["train", "--dataset", str(trained / "dataset"), "--out", str(tmp_path / "run"), "--method",
                        "regression_rnn", "--preset", "tiny", "--max-steps", "2",
                        "--config", str(tmp_path / "tiny.yaml")],
                       capsys)
    assert rc == 2
    _one_line_error(err, "training loss is nan at step 1", "no checkpoint was written")
    assert "is kept" not in err and str(tmp_path / "run") not in err


def test_predictions_that_cannot_be_integrated_are_refused_naming_the_checkpoint(trained, tmp_path, capsys,
                                                                               monkeypatch):
    """Finite but absurd predictions make the integrated attitude no rotation (scipy's SVD fails): one line."""
    import training.evaluation.evaluate as ev

    def svd_fails(*args, **kwargs):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(ev, "window_end_errors", svd_fails)
    rc, err = _run_cli(["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(trained / "dataset"),
                        "--out", str(tmp_path / "ev"), *EVAL], capsys)
    assert rc == 2
    _one_line_error(err, "cannot be integrated", str(trained / "run" / "best.pt"))
    assert not (tmp_path / "ev").exists()
