"""Long work shows progress with a rate and an ETA: train, evaluate, predict, recover, and the workflow's terminal."""

from __future__ import annotations

import io
import logging
import os
import re
import time
from pathlib import Path

import pytest

from biasgt.workflow.job_progress import JobProgress, last_line, running_lines
from pipeline.progress import progress

#: tqdm's "[elapsed<remaining, rate]" part of a progress line: the ETA and the rate.
RATE_ETA = re.compile(r"\[\d\d:\d\d<\d\d:\d\d, +[\d.]+(\w+)/s[,\]]")


def _progress_lines(caplog: pytest.LogCaptureFixture, prefix: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith(prefix)]


def test_progress_off_a_terminal_is_log_lines_with_rate_and_eta(caplog) -> None:
    logger = logging.getLogger("biasgt.test.progress")
    with caplog.at_level(logging.INFO, logger=logger.name):
        bar = progress(4, desc="work", unit="step", logger=logger, interval_s=0.0)
        for _ in range(4):
            time.sleep(0.01)
            bar.update(1)
        bar.close()
    lines = _progress_lines(caplog, "work:")
    assert len(lines) >= 2 and "4/4" in lines[-1]
    assert RATE_ETA.search(lines[-1]).group(1) == "step"


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from window_data import make_window_dataset

    return make_window_dataset(tmp_path_factory.mktemp("progress"), splits={"train": 1, "val": 1, "test": 1},
                               duration_s=5.0)


def test_train_evaluate_and_predict_report_progress(data: Path, tmp_path: Path, caplog) -> None:
    from training.evaluation.evaluate import evaluate_reference
    from training.fit.checkpoint import load_run
    from training.deploy.predict import predict_sequence
    from pipeline.store import read_store
    from window_data import train_tiny

    with caplog.at_level(logging.INFO):
        train_tiny(data, tmp_path / "run", "diffusion_rnn")
        evaluate_reference("zero", data)
        predict_sequence(load_run(tmp_path / "run"), read_store(data.parent / "stores" / "test0"), samples=2, steps=2)
    for prefix, unit in (("train diffusion_rnn:", "step"), ("evaluate:", "window"), ("predict test0", "window")):
        lines = _progress_lines(caplog, prefix)
        assert lines and RATE_ETA.search(lines[-1]).group(1) == unit, (prefix, lines)


def test_recover_reports_its_rounds(tmp_path: Path, caplog) -> None:
    from biasgt.cli.app import main

    assert main(["-q", "simulate", "--duration", "10", "--seed", "4", str(tmp_path / "sim")]) == 0
    with caplog.at_level(logging.INFO, logger="recovery.recover"):
        assert main(["recover", str(tmp_path / "sim"), "--out", str(tmp_path / "rec"), "--noise", "fixed"]) == 0
    lines = _progress_lines(caplog, "recover sim:")
    assert lines and "5/5" in lines[-1] and RATE_ETA.search(lines[-1]).group(1) == "round"


def test_workflow_terminal_gets_one_line_per_running_job(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    (logs / "train").mkdir(parents=True)
    (logs / "ingest").mkdir()
    done = logs / "ingest" / "a.log"
    done.write_text("2026-12-02 14:36:26,395 INFO biasgt.workflow: wrote results/ingest/a\n")
    old = time.time() - 100
    os.utime(done, (old, old))
    running = logs / "train" / "m_seed0.log"
    running.write_text("x\n2026-12-02 14:36:27,000 INFO training.fit.train: train m:  40%|####  | 32/80 "
                       "[00:41<01:02, 0.77step/s]\n")
    assert last_line(running).startswith("train m:  40%")
    assert running_lines(logs, time.time() - 10) == [f"  [running] logs/train/m_seed0.log: {last_line(running)}"]
    echo = io.StringIO()
    with JobProgress(tmp_path, echo, interval_s=0.05) as jobs:
        jobs.write("snakemake line\n")
        time.sleep(0.02)
        running.write_text(running.read_text() + "train m:  50%|#####  | 40/80 [00:51<00:52, 0.77step/s]\n")
        time.sleep(0.2)
    text = echo.getvalue()
    assert "snakemake line" in text and "[running] logs/train/m_seed0.log: train m:  50%" in text
    assert "ingest/a.log" not in text
