"""A tiny simulated window dataset (train / val / test sequences) for the learning-stage tests."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.bias_table import BiasTrack
from pipeline.sim import ImuNoiseConfig, SimConfig, simulate
from pipeline.store import write_store
from synth import write_recovery_folder
from training.data.windows import WindowConfig, WindowSource, build_window_dataset

#: Random walks (gyro, acc) written to recovery.json, as a recovery would.
RW = (2e-4, 3e-3)
GRAVITY = (0.0, 0.0, -9.81)


def write_truth_recovery(folder: Path, sim, every: int = 10) -> Path:
    """A recovery folder holding the simulator's true bias as keyframes every ``every`` IMU samples,
    written by the recovery stage's own writer."""
    tr = sim.truth
    k = np.arange(0, len(tr.t_ns), every)
    bias = np.hstack([tr.bias_gyro_radps, tr.bias_acc_mps2])[k]
    report = {
        "noise": {"gyro_random_walk": RW[0], "acc_random_walk": RW[1]},
        "gravity_world_mps2": list(GRAVITY),
        "pose_time_offset_s": 0.0,
        "T_imu_pose": {"p_m": [0.0, 0.0, 0.0],
                       "quat_wxyz": Rotation.identity().as_quat(scalar_first=True).tolist()},
    }
    return write_recovery_folder(folder, BiasTrack(tr.t_ns[k], bias, np.full_like(bias, 1e-5)), report)


def make_window_dataset(root: Path, *, splits: dict[str, int] | None = None, duration_s: float = 8.0,
                        rate_hz: float = 200.0, window_s: float = 1.0) -> Path:
    """Simulate sequences (``splits``: split -> count), recover them from truth, window them into ``root/dataset``."""
    splits = splits or {"train": 2, "val": 1, "test": 2}
    sources, seed = [], 0
    for split, count in splits.items():
        for i in range(count):
            seed += 1
            name = f"{split}{i}"
            sim = simulate(SimConfig(duration_s=duration_s, seed=seed, name=name, imu=ImuNoiseConfig(rate_hz=rate_hz)))
            store = write_store(dataclasses.replace(sim.sequence, name=name), root / "stores" / name)
            rec = write_truth_recovery(root / "rec" / name, sim)
            sources.append(WindowSource(name, split, store, rec))
    out = root / "dataset"
    build_window_dataset(sources, out, WindowConfig(window_s=window_s, overlap=0.5))
    return out


#: A training plan (the workflow's ``training:`` section) that trains in seconds: tiny preset, a few steps.
TINY_PLAN = {"preset": "tiny", "options": {"max_steps": 4, "batch_size": 8, "val_every": 2, "checkpoint_every": 2,
                                           "device": "cpu", "warmup_steps": 1}}


def train_tiny(dataset: Path, out_dir: Path, method: str, steps: int = 4) -> Path:
    """Train ``method`` for ``steps`` steps at the tiny preset through the workflow's step."""
    from biasgt.workflow.learning import TrainingPlan, train_step

    plan = {**TINY_PLAN, "methods": [method], "options": {**TINY_PLAN["options"], "max_steps": steps}}
    return train_step(dataset, out_dir, TrainingPlan.from_mapping(plan).run_settings(method, 0), threads=1)
