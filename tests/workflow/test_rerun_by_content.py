"""The learning jobs depend on the window dataset's content, not its time stamp; a dry run says so in one line."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
import yaml

from biasgt.cli.app import main
from biasgt.workflow.learning import dataset_checksum
from biasgt.workflow.run import run_workflow
from biasgt.workflow.run_summary import dry_run_jobs, dry_run_summary

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("workflow_snakemake")]


TARGETS = ["results/evaluation/diffusion_rnn/seed0", "results/evaluation/regression_rnn/seed0",
           "results/evaluation/zero"]


def _config(path: Path, **sections) -> Path:
    data = {
        "sequences": [{"name": f"s_{split}", "source": "simulate", "duration_s": 8, "seed": i + 1, "split": split}
                      for i, split in enumerate(("train", "val", "test"))],
        "windows": {"accept_warn": True},
        "training": {"methods": ["diffusion_rnn", "regression_rnn"], "seeds": [0], "preset": "tiny",
                     "options": {"max_steps": 2, "batch_size": 8, "val_every": 2, "checkpoint_every": 2,
                                 "warmup_steps": 1}},
        "evaluation": {"samples": 2, "steps": 2, "samplers": ["ddim"], "references": ["zero"]},
        **sections,
    }
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def learned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    workdir = tmp_path_factory.mktemp("content")
    run_workflow(config_file=_config(workdir / "config.yaml"), workdir=workdir, cores=2, echo=io.StringIO(),
                    targets=TARGETS)
    return workdir


def _plan(workdir: Path, cfg: Path) -> str:
    echo = io.StringIO()
    run_workflow(config_file=cfg, workdir=workdir, dry_run=True, echo=echo,
                    targets=TARGETS)
    return echo.getvalue()


def test_a_margin_that_changes_no_verdict_retrains_nothing(learned: Path, capsys) -> None:
    run_dir = learned / "results" / "training" / "diffusion_rnn" / "seed0"
    before = (run_dir / "run.json").stat().st_mtime_ns, dataset_checksum(learned / "results" / "windows" / "dataset")
    cfg = _config(learned / "margin.yaml", validation={"margin": 0.12})
    summary = dry_run_summary(_plan(learned, cfg))
    assert "validate 3 (parameters changed)" in summary and "windows 1" in summary
    assert "train, evaluate, evaluate_reference run only if the window dataset's content changes" in summary
    run_workflow(config_file=cfg, workdir=learned, cores=2, echo=io.StringIO(),
                    targets=TARGETS)
    after = (run_dir / "run.json").stat().st_mtime_ns, dataset_checksum(learned / "results" / "windows" / "dataset")
    assert after == before  # the dataset was rewritten with the same content: no training ran
    assert dry_run_jobs(_plan(learned, cfg)) == []


def test_the_sample_count_reruns_only_the_diffusion_models_evaluation(learned: Path) -> None:
    # on top of a run at margin 0.12 (the test above leaves one; made here when this test runs first), so that
    # only the sample count differs
    margin = _config(learned / "margin.yaml", validation={"margin": 0.12})
    if dry_run_jobs(_plan(learned, margin)):
        run_workflow(config_file=margin, workdir=learned, cores=2, echo=io.StringIO(), targets=TARGETS)
    jobs = dry_run_jobs(_plan(learned, _config(learned / "samples.yaml", validation={"margin": 0.12},
                                                evaluation={"samples": 3, "steps": 2, "samplers": ["ddim"],
                                                            "references": ["zero"]})))
    assert [rule for rule, _ in jobs] == ["evaluate"]  # diffusion_rnn's: not regression_rnn's, not zero's


def test_dry_run_ends_with_one_line(learned: Path, capsys) -> None:
    cfg = _config(learned / "margin2.yaml", validation={"margin": 0.15})
    assert main(["run", "--config", str(cfg), "--directory", str(learned), "--dry-run", "--target",
                 "results/evaluation/zero"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("dry run: 5 jobs would run: validate 3 (parameters changed)")


def test_a_table_behind_the_config_is_marked_out_of_date(learned: Path, capsys) -> None:
    """``biasgt run --until ingest`` after the training section changed: Table I is not shown as a result but
    marked out of date, naming what would rerun; under the config it was made with, its headline shows."""
    base = _config(learned / "table.yaml")
    assert main(["run", "--config", str(base), "--directory", str(learned), "--target", "table"]) == 0
    capsys.readouterr()
    changed = _config(learned / "steps.yaml", training={"methods": ["diffusion_rnn", "regression_rnn"], "seeds": [0],
                                                         "preset": "tiny", "options": {"max_steps": 3, "batch_size": 8,
                                                                                       "val_every": 2, "warmup_steps": 1,
                                                                                       "checkpoint_every": 2}})
    assert main(["run", "--config", str(changed), "--directory", str(learned), "--until", "ingest"]) == 0
    table = [ln for ln in capsys.readouterr().out.splitlines() if "Table I" in ln]
    assert table == ["  Table I: OUT OF DATE, not shown: the config changed what it is made of (train 2 (parameters "
                     "changed); evaluate 2 (after an upstream job); table 1 (after an upstream job) would rerun); "
                     "'biasgt run' without --until/--target brings it up to date"], table
    assert main(["run", "--config", str(base), "--directory", str(learned), "--until", "ingest"]) == 0
    table = [ln for ln in capsys.readouterr().out.splitlines() if "Table I" in ln]
    assert len(table) == 1 and table[0].startswith("  Table I: best average "), table
