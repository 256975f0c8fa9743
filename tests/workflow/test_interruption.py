"""Interrupted writes leave nothing half-written, and a stage never deletes another stage's output."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from pipeline.files.atomic import atomic_dir

REPO = Path(__file__).resolve().parents[2]


def _leftovers(folder: Path) -> list[str]:
    """Temporary siblings the atomic writers create (``.NAME.*.tmp`` / ``.NAME.*.old``)."""
    return sorted(p.name for p in folder.rglob(".*") if p.name.endswith((".tmp", ".old")))


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


# A child that is stopped while it is inside atomic_dir, half-way through its content.
_CHILD = textwrap.dedent("""
    import signal, sys, time
    from pathlib import Path
    from pipeline.files.atomic import atomic_dir
    from biasgt.cli.app import _raise_terminated
    signal.signal(signal.SIGTERM, _raise_terminated)
    # Python's own SIGINT handler, as in a foreground process: started from a background job
    # (e.g. 'make test &' in a non-interactive shell) a child inherits SIGINT ignored
    signal.signal(signal.SIGINT, signal.default_int_handler)
    out = Path(sys.argv[1])
    with atomic_dir(out, owned={"bias.csv", "recovery.json"}) as tmp:
        (tmp / "bias.csv").write_text("t_ns,bg_x\\n1,")  # half a file
        print("ready", flush=True)
        time.sleep(60)
        (tmp / "recovery.json").write_text("{}")
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_inside_atomic_dir_removes_the_temporary_folder(tmp_path: Path, sig: int) -> None:
    out = tmp_path / "rec"
    out.mkdir()
    (out / "bias.csv").write_text("old complete file\n")
    (out / "bias_imu.parquet").write_text("another stage's output\n")
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(out)], stdout=subprocess.PIPE, env=_env(), text=True)
    assert child.stdout.readline().strip() == "ready"
    child.send_signal(sig)
    assert child.wait(timeout=30) != 0
    assert _leftovers(tmp_path) == []
    assert (out / "bias.csv").read_text() == "old complete file\n"  # untouched
    assert (out / "bias_imu.parquet").exists()


def test_owned_replaces_only_the_writers_files(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    (out / "validation").mkdir(parents=True)
    (out / "validation" / "validation.json").write_text("{}")
    (out / "bias_imu.parquet").write_text("interpolation")
    (out / "bias.csv").write_text("old")
    (out / "trajectory_tum.txt").write_text("stale, not written this time")
    with atomic_dir(out, owned={"bias.csv", "trajectory_tum.txt"}) as tmp:
        (tmp / "bias.csv").write_text("new")
    assert (out / "bias.csv").read_text() == "new"
    assert not (out / "trajectory_tum.txt").exists()  # ours, not rewritten: gone
    assert (out / "bias_imu.parquet").read_text() == "interpolation"
    assert (out / "validation" / "validation.json").exists()
    assert _leftovers(tmp_path) == []


def test_failure_before_the_swap_keeps_every_file(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    out.mkdir()
    (out / "bias.csv").write_text("old")
    (out / "bias_imu.parquet").write_text("interpolation")
    with pytest.raises(RuntimeError):
        with atomic_dir(out, owned={"bias.csv"}) as tmp:
            (tmp / "bias.csv").write_text("new")
            raise RuntimeError("solver failed")
    assert {p.name: p.read_text() for p in out.iterdir()} == {"bias.csv": "old", "bias_imu.parquet": "interpolation"}
    assert _leftovers(tmp_path) == []


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from biasgt.cli.app import main

    out = tmp_path_factory.mktemp("sim") / "sim20"
    assert main(["-q", "simulate", "--duration", "20", "--seed", "1", str(out)]) == 0
    return out


def _biasgt(*args: str) -> list[str]:
    return [sys.executable, "-c", "import sys; from biasgt.cli.app import main; sys.exit(main())", *args]


def test_rerunning_recover_keeps_other_stages_outputs(tmp_path: Path, sim_folder: Path) -> None:
    out = tmp_path / "rec01"
    run = subprocess.run(_biasgt("-q", "recover", str(sim_folder), "--out", str(out)), env=_env(),
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    (out / "bias_imu.parquet").write_text("interpolation output")
    (out / "validation").mkdir()
    (out / "validation" / "validation.json").write_text("{}")
    first = (out / "bias.csv").stat().st_mtime_ns
    run = subprocess.run(_biasgt("-q", "recover", str(sim_folder), "--out", str(out)), env=_env(),
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert (out / "bias.csv").stat().st_mtime_ns != first
    assert (out / "bias_imu.parquet").read_text() == "interpolation output"
    assert (out / "validation" / "validation.json").exists()


@pytest.mark.parametrize("delay_s", [0.3, 0.8, 1.2, 1.6])
def test_sigterm_during_recover_leaves_a_complete_output_or_none(tmp_path: Path, sim_folder: Path,
                                                                  delay_s: float) -> None:
    out = tmp_path / "rec"
    child = subprocess.Popen(_biasgt("-q", "recover", str(sim_folder), "--out", str(out)), env=_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(delay_s)
    child.send_signal(signal.SIGTERM)
    rc = child.wait(timeout=120)
    assert "Traceback" not in child.stderr.read()
    assert _leftovers(tmp_path) == []
    if rc != 0:  # stopped by our handler (143), or by the default action before it was installed (-15)
        assert rc in (128 + signal.SIGTERM, -signal.SIGTERM)
    if rc == 0 or out.exists():  # finished before the signal, or the signal came after the output's commit
        assert {"bias.csv", "recovery.json"} <= {p.name for p in out.iterdir()}
        assert json.loads((out / "recovery.json").read_text())["keyframes"] > 0


# ----------------------------------------------------------------------------- output location

_WRITING_COMMANDS = [
    ["simulate", "--duration", "5", "{out}"],
    ["convert", "{sim}", "--out", "{out}"],
    ["recover", "{sim}", "--out", "{out}"],
    ["interpolate", "{sim}", "--imu", "{sim}", "--out", "{out}/bias.parquet"],
    ["validate", "{sim}", "--recovery", "{sim}", "--out", "{out}"],
    ["windows", "--seq", "s", "train", "{sim}", "{sim}", "--out", "{out}"],
    ["report", "--ingest", "{sim}", "--out", "{out}/q.html"],
]


@pytest.mark.parametrize("command", _WRITING_COMMANDS, ids=lambda c: c[0])
def test_output_under_a_file_is_refused_before_any_work(tmp_path: Path, command: list[str], capsys) -> None:
    from biasgt.cli.app import main

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    argv = [a.format(out=blocker / "out", sim=tmp_path / "missing-input") for a in command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a_file is a file, not a folder" in err


def test_read_only_output_folder_is_refused_before_any_work(tmp_path: Path) -> None:
    """A read-only mount (permission bits do not stop root): bound read-only in a private mount namespace."""
    import shlex
    import shutil

    ro = tmp_path / "read_only"
    ro.mkdir()
    mount = f"mount --bind -o ro {shlex.quote(str(ro))} {shlex.quote(str(ro))}"
    probe = (subprocess.run(["unshare", "-m", "sh", "-c", f"{mount} && touch {shlex.quote(str(ro))}/x"],
                            capture_output=True, text=True) if shutil.which("unshare") else None)
    if probe is None or "Read-only file system" not in probe.stderr:
        pytest.skip("cannot make a read-only mount here (needs unshare and mount rights)")
    command = shlex.join(_biasgt("simulate", "--duration", "5", str(ro / "sim")))
    run = subprocess.run(["unshare", "-m", "sh", "-c", f"{mount} && exec {command}"], env=_env(),
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stderr.count("\n") == 1 and "is not writable" in run.stderr
    assert list(ro.iterdir()) == []


def test_sigterm_inside_an_extension_import_is_a_termination_not_a_traceback(capsys, monkeypatch) -> None:
    """A signal while a C extension initialises comes back as that module's ImportError, caused by
    Terminated (seen with gtsam): the CLI still reports a termination, in one line."""
    from biasgt.cli import app as cli

    def import_interrupted(args):
        try:
            raise cli.Terminated()
        except cli.Terminated as exc:
            raise ImportError("initialization failed") from exc

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    args = parser.parse_args(["inspect", "x"])
    monkeypatch.setattr(parser, "parse_args", lambda argv=None: args)
    monkeypatch.setattr(args, "func", import_interrupted)
    assert cli.main([]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err
    assert err.strip() == "biasgt inspect: terminated (SIGTERM); nothing half-written was left"


# ----------------------------------------------------------------------------- a full disk


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _pyarrow_disk_full(*args, **kwargs):
    """What pyarrow raises on a full disk (its text carries the errno too)."""
    raise OSError(errno.ENOSPC, "Error writing bytes to file. Detail: [errno 28] No space left on device")


def _no_space_line(err: str, folder: Path) -> None:
    errors = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(errors) == 1, err
    assert "no space left on device" in errors[0] and f"folder {folder}" in errors[0], errors[0]
    assert "Traceback" not in err and "Errno" not in err


def test_a_full_disk_during_recover_is_one_line_and_writes_nothing(tmp_path: Path, sim_folder: Path, capsys,
                                                                   monkeypatch) -> None:
    import recovery.outputs
    from biasgt.cli.app import main

    monkeypatch.setattr(recovery.outputs, "write_tum", _disk_full)
    out = tmp_path / "out" / "rec"
    assert main(["-q", "recover", str(sim_folder), "--out", str(out), "--noise", "fixed"]) == 2
    _no_space_line(capsys.readouterr().err, out.parent)
    assert not out.exists() and _leftovers(tmp_path) == []


def test_a_full_disk_during_validate_is_one_line_and_keeps_the_old_output(tmp_path: Path, sim_folder: Path,
                                                                         capsys, monkeypatch) -> None:
    import validation.outputs
    from biasgt.cli.app import main

    rec = tmp_path / "rec"
    assert main(["-q", "recover", str(sim_folder), "--out", str(rec), "--noise", "fixed"]) == 0
    out = tmp_path / "val"
    out.mkdir()
    (out / "validation.json").write_text("old")
    monkeypatch.setattr(validation.outputs.pq, "write_table", _pyarrow_disk_full)
    capsys.readouterr()
    assert main(["-q", "validate", str(sim_folder), "--recovery", str(rec), "--out", str(out)]) == 2
    _no_space_line(capsys.readouterr().err, tmp_path)
    assert (out / "validation.json").read_text() == "old" and _leftovers(tmp_path) == []


def test_a_full_disk_outside_the_atomic_writers_is_the_same_one_line(tmp_path: Path, capsys, monkeypatch) -> None:
    from biasgt.cli.app import main
    from biasgt.cli.commands import simulate

    monkeypatch.setattr(simulate, "run", _disk_full)  # registered as the command's func when main builds the parser
    assert main(["simulate", str(tmp_path / "sim")]) == 2
    _no_space_line(capsys.readouterr().err, tmp_path)
