"""Data-parallel training: 2 gloo processes under torchrun train the weights 1 process trains.

Same seed, same global batch (16 windows: 8 per process), 300 tiny steps. Not bit-exact: the
all-reduce averages two half-batch gradient means where one process takes one full-batch mean,
so float32 sums are rounded in another order (~1e-8 relative after a few steps), and training
carries such differences forward and can amplify them: here ~3e-7 after 300 steps at lr 1e-3,
but ~1e-3 after 200 steps at lr 3e-3 on the same data (the trajectory itself is that
sensitive). The tolerance: the whole weight vector agrees to 1e-5 relative (norm of the
difference over norm of the weights).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import torch

from training.fit.checkpoint import LAST, load_checkpoint

sys.path.insert(0, str(Path(__file__).parents[1]))
from toy_windows import Kind, Toy, write_toy_dataset  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def test_two_gloo_processes_match_one_process(tmp_path):
    ds = write_toy_dataset(tmp_path / "ds", Toy(kind=Kind.LINEAR, samples=16), train=96, val=32, test=0)
    (tmp_path / "c.yaml").write_text("batch_size: 16\nval_every: 50\ncheckpoint_every: 50\nlr: 0.001\n"
                                     "warmup_steps: 10\ndevice: cpu\n")
    args = ["-m", "biasgt.cli", "-q", "train", "--dataset", str(ds), "--method", "diffusion_rnn", "--preset", "tiny",
            "--max-steps", "300", "--config", str(tmp_path / "c.yaml")]
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    subprocess.run([sys.executable, *args, "--out", str(tmp_path / "one")], env=env, check=True)
    subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2", *args,
                    "--out", str(tmp_path / "two")], env=env, check=True)

    one, two = (load_checkpoint(tmp_path / name / LAST)["model"] for name in ("one", "two"))
    keys = [k for k in one if one[k].is_floating_point() and not k.startswith("normalizer")]
    a = torch.cat([one[k].flatten() for k in keys])
    b = torch.cat([two[k].flatten() for k in keys])
    assert 0 < float((a - b).norm() / a.norm()) < 1e-5
    summary = json.loads((tmp_path / "two" / "run.json").read_text())
    assert summary["processes"] == 2 and summary["steps"] == 300
    assert not list((tmp_path / "two").glob("*.tmp"))  # one writer, every write completed


def test_workflow_train_step_launches_torchrun_for_several_processes(tmp_path, monkeypatch):
    """training.processes > 1: the train job runs 'biasgt train' under torchrun inside the job."""
    from training.config import TrainingPlan
    from biasgt.workflow.learning import train_step

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    ds = write_toy_dataset(tmp_path / "ds", Toy(kind=Kind.LINEAR, samples=16), train=32, val=16, test=0)
    plan = TrainingPlan.from_mapping({"preset": "tiny", "processes": 2, "options": {
        "max_steps": 20, "batch_size": 8, "val_every": 10, "checkpoint_every": 10, "device": "cpu"}})
    out = train_step(ds, tmp_path / "run", plan.run_settings("regression_rnn", 0), processes=plan.processes)
    summary = json.loads((out / "run.json").read_text())
    assert summary["processes"] == 2 and summary["steps"] == 20 and summary["method"] == "regression_rnn"
