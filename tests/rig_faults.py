"""A rig's usual faults, written into the EuRoC ASL folders of two generators: the project's simulator
(:mod:`pipeline.sim`, ``mav0/mocap0``) and the independent one (:mod:`independent`, ``mav0/vicon0``).

:func:`write_recording` writes a recording with an unknown extrinsic (20 deg, 5 cm) and an optional clock
offset; the fault functions then edit its CSV files the way a rig's software gets them wrong: positions in
millimetres, a long pose dropout, occluded frames written as the origin with the identity orientation,
quaternions written w-last under a w-first header, two accelerometer or gyro columns swapped, IMU stamps
in milliseconds.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

import independent as ind
from pipeline.sim import SimConfig, simulate
from pipeline.sim.config import PoseStreamConfig
from pipeline.sim.writer import write_simulation

GENERATORS = ("sim", "independent")


@dataclass(frozen=True)
class Truth:
    """What the generator knows: the true bias at the IMU stamps ([N, 3] each) and the clock offset."""

    t_ns: np.ndarray
    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray
    clock_offset_s: float

    def bias_errors(self, result) -> tuple[np.ndarray, np.ndarray]:
        """A recovery's gyro and accelerometer bias minus the truth at its keyframes, [K, 3] each."""
        true = [np.column_stack([np.interp(result.t_ns, self.t_ns, b[:, c]) for c in range(3)])
                for b in (self.bias_gyro_radps, self.bias_acc_mps2)]
        return result.bias_gyro_radps - true[0], result.bias_acc_mps2 - true[1]


def write_recording(generator: str, root: Path, *, duration_s: float = 40.0, seed: int = 0,
                    clock_offset_s: float = 0.02) -> Truth:
    """An ASL folder of ``generator`` at ``root`` (no ground truth, the marker's extrinsic not in a file)."""
    if generator == "sim":
        sim = simulate(SimConfig(duration_s=duration_s, seed=seed, poses=PoseStreamConfig(
            clock_offset_s=clock_offset_s, extrinsic_rotvec_deg=(10.0, -5.0, 17.0),
            extrinsic_translation_xyz_m=(0.03, 0.02, -0.03), extrinsic_known=False)))
        write_simulation(sim, root)
        shutil.rmtree(root / "mav0" / "state_groundtruth_estimate0")
        t = sim.truth
        return Truth(t.t_ns, t.bias_gyro_radps, t.bias_acc_mps2, t.clock_offset_s)
    seq = ind.make_sequence(duration_s, seed=seed, clock_offset_s=clock_offset_s,
                            T_imu_marker=ind.extrinsic((10.0, -5.0, 17.0), (0.03, 0.02, -0.03)))
    ind.write_euroc(seq, root, extrinsic_known=False, with_ground_truth=False)
    return Truth(seq.t_ns, seq.bias_gyro_radps, seq.bias_acc_mps2, seq.clock_offset_s)


def pose_csv(root: Path) -> Path:
    """The recording's pose file (``mocap0`` or ``vicon0``)."""
    return next(p for p in (root / "mav0" / "mocap0" / "data.csv", root / "mav0" / "vicon0" / "data.csv")
                if p.exists())


def imu_csv(root: Path) -> Path:
    return root / "mav0" / "imu0" / "data.csv"


def _edit(path: Path, change) -> None:
    table = pd.read_csv(path, dtype={0: np.int64})
    change(table)
    table.to_csv(path, index=False, float_format="%.17g")


def positions_scaled(root: Path, factor: float) -> None:
    """Positions written in another unit (``factor`` 1000: millimetres)."""
    def change(t):
        t.iloc[:, 1:4] = t.iloc[:, 1:4].to_numpy() * factor
    _edit(pose_csv(root), change)


def _rel_s(t: pd.DataFrame) -> np.ndarray:
    stamps = t.iloc[:, 0].to_numpy(np.int64)
    return (stamps - stamps[0]) / 1e9


def drop_poses(root: Path, start_s: float, length_s: float) -> None:
    """No poses from ``start_s`` for ``length_s`` (seconds after the first pose)."""
    path = pose_csv(root)
    table = pd.read_csv(path, dtype={0: np.int64})
    rel = _rel_s(table)
    table[(rel < start_s) | (rel > start_s + length_s)].to_csv(path, index=False, float_format="%.17g")


def placeholders(root: Path, start_s: float, length_s: float) -> None:
    """Poses from ``start_s`` for ``length_s`` written as the origin with the identity orientation."""
    def change(t):
        rel = _rel_s(t)
        rows = (rel >= start_s) & (rel < start_s + length_s)
        t.iloc[rows, 1:8] = np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (int(rows.sum()), 1))
    _edit(pose_csv(root), change)


def flip_imu_axis(root: Path, sensor: str, axis: int) -> None:
    """One axis of ``sensor`` (``"gyro"`` or ``"acc"``) written with the wrong sign."""
    column = (1 if sensor == "gyro" else 4) + axis
    def change(t):
        t.iloc[:, column] = -t.iloc[:, column].to_numpy()
    _edit(imu_csv(root), change)


def quaternion_w_last(root: Path) -> None:
    """Quaternions written x, y, z, w under the w-first header."""
    def change(t):
        t.iloc[:, 4:8] = t.iloc[:, [5, 6, 7, 4]].to_numpy()
    _edit(pose_csv(root), change)


def swap_imu_columns(root: Path, sensor: str, a: int, b: int) -> None:
    """Two axes of ``sensor`` (``"gyro"`` or ``"acc"``) swapped in the IMU file."""
    base = 1 if sensor == "gyro" else 4
    def change(t):
        cols = [base + a, base + b]
        t.iloc[:, cols] = t.iloc[:, cols[::-1]].to_numpy()
    _edit(imu_csv(root), change)


def imu_stamps_in_ms(root: Path) -> None:
    """The IMU file's stamps written in milliseconds (rounded) under its nanosecond header."""
    def change(t):
        t.iloc[:, 0] = np.round(t.iloc[:, 0].to_numpy(np.int64) / 1e6).astype(np.int64)
    _edit(imu_csv(root), change)
