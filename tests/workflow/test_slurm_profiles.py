"""The shipped SLURM profiles: a CPU-only one that asks for no GPU, and SLURM's own refusal text on failure."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import yaml

from biasgt.cli.app import main
from biasgt.workflow.config import PROFILES_DIR
from biasgt.workflow.run import describe_failure, resolve_profile

REPO = Path(__file__).resolve().parents[2]


def test_cpu_profile_asks_for_no_gpu_and_little_memory() -> None:
    profile = yaml.safe_load((resolve_profile("slurm-cpu") / "config.yaml").read_text())
    gpu = yaml.safe_load((resolve_profile("slurm") / "config.yaml").read_text())
    assert "gpu" not in profile["set-resources"]["train"] and profile["set-threads"]["train"] <= 2
    assert all(eval(str(r["mem_mb"]), {"attempt": 1}) <= 8000 for r in profile["set-resources"].values())
    # everything else as in the GPU profile
    assert {k: v for k, v in profile.items() if k not in ("set-resources", "set-threads")} == {
        k: v for k, v in gpu.items() if k not in ("set-resources", "set-threads")}


def test_cpu_profile_dry_run_plans_train_jobs_without_a_gpu(tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"sequences": [
        {"name": n, "source": "simulate", "duration_s": 3, "seed": i + 1, "split": n}
        for i, n in enumerate(("train", "val", "test"))],
        "training": {"methods": ["regression_rnn"], "seeds": [0], "preset": "tiny"}}))
    assert main(["-v", "run", "--config", str(cfg), "--directory", str(tmp_path), "--profile", "slurm-cpu",
                 "--dry-run"]) == 0
    err = capsys.readouterr().err
    blocks = re.findall(r"rule train:\n((?:\s+\w+: .*\n)+)", err)
    assert blocks and all("gpu" not in b and "mem_mb=8000" in b for b in blocks)


def test_the_local_slurm_test_runs_a_shipped_profile_as_it_is() -> None:
    sys.path.insert(0, str(REPO / "tests" / "cluster"))
    try:
        import slurm_local
    finally:
        sys.path.pop(0)
    args = slurm_local.slurm_args()
    assert args[:2] == ["--profile", slurm_local.PROFILE] and (PROFILES_DIR / slurm_local.PROFILE).is_dir()
    assert not any(a.startswith(("--default-resources", "--set-resources", "--set-threads")) for a in args)


def test_the_local_slurm_test_finds_a_submitted_checkpoint_job(tmp_path: Path) -> None:
    """The window dataset is a Snakemake checkpoint: the SLURM test must find its announcement in the log
    (Snakemake writes ``checkpoint windows:`` where a rule says ``rule ...:``)."""
    sys.path.insert(0, str(REPO / "tests" / "cluster"))
    try:
        import slurm_local
    finally:
        sys.path.pop(0)
    log_dir = tmp_path / ".snakemake" / "log"
    log_dir.mkdir(parents=True)
    (log_dir / "2026-12-02T171648.1.snakemake.log").write_text("\n".join([
        "[Wed Dec  2 17:18:02 2026]", "checkpoint windows:", "    output: results/windows/dataset",
        "    log: logs/windows/dataset.log", "    jobid: 20", "DAG of jobs will be updated after completion.",
        "Job 20 has been submitted with SLURM jobid 5 (log: x/5.log).",
        "[Wed Dec  2 17:18:34 2026]", "rule table:", "    output: results/evaluation/table.csv",
        "    log: logs/table/dataset.log", "    jobid: 21",
        "Job 21 has been submitted with SLURM jobid 8 (log: x/8.log).", ""]))
    assert slurm_local.submitted_jobs(tmp_path) == [("windows", "dataset", "5"), ("table", "dataset", "8")]


def test_sbatch_refusal_is_shown(tmp_path: Path) -> None:
    lines = [
        "[Tue Dec  1 19:30:00 2026] Group job learning (jobs in lexicogr. order):",
        "    rule train:", "        jobid: 7", "        wildcards: method=regression_rnn, seed=0",
        "SLURM sbatch failed. The error message was 'sbatch: error: Batch job submission failed: Requested node "
        "configuration is not available'.",
        "    sbatch call:", "        sbatch --gpus=1 ...",
        "    message: Error in group learning",
        "    Error in rule train:", "        jobid: 7", "        output: results/training/regression_rnn/seed0",
        "        log: logs/train/regression_rnn_seed0.log (check log file(s) for error details)",
    ]
    text = describe_failure(lines, tmp_path)
    assert text.startswith("SLURM refused to queue rule 'train': sbatch: error: Batch job submission failed: "
                           "Requested node configuration is not available")
    assert "--profile slurm-cpu" in text
