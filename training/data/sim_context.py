"""A simulated window dataset whose bias is a fixed function of what a context model is given.

The check that the learning *can* learn (benchmarks/learning/context_learning.py, tests/learning/test_context_learning.py).
Every sequence is one IMU unit:

* it starts with ``rest_s`` seconds at rest at a near-level attitude (tilt below ``max_tilt_deg``,
  any yaw), then moves (sums of sinusoids in angular rate and world acceleration, faded in);
* its temperature warms up ``T(t) = ambient + rise (1 - exp(-t / tau_s))``, ambient and rise drawn
  per sequence, and is reported with the IMU;
* its bias is ``b(t) = turn_on + unit + coeff * (T(t) - reference_degc)``: ``unit`` and ``coeff``
  [6] are the same in every sequence (one IMU unit: the temperature dependence); ``turn_on`` is
  drawn per sequence, on every gyro axis and on the accelerometer's z axis only (near-level at rest,
  so the rest shows it: the component along gravity is the observable one).

So the bias of every window is a fixed function of the start rest's IMU mean and temperature and
the window's temperature: a model given those (``use_temperature`` and the start-rest context,
:mod:`training.context.model`) can predict it; a 1-s model without context cannot know the turn-on.

The reference states come from the project's own integrator run over the whole sequence with the
true readings, so the true bias integrates every window to its reference end up to the noise.
Written in the real formats: the window dataset (:func:`training.data.dataset.write_dataset`) and its
sequence records (``context/``, :mod:`training.data.records`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.files.atomic import atomic_dir
from pipeline.geometry.integration import integrate_numpy
from pipeline.geometry.so3_numpy import so3_exp_np
from pipeline.types import DEFAULT_GRAVITY_MPS2, Split
from training.data.records import CONTEXT_DIR
from training.data.dataset import SequenceWindows, write_dataset

__all__ = ["RestSim", "simulate_rest_sequence", "write_rest_sim_dataset"]


@dataclass(frozen=True)
class RestSim:
    """Sizes and error model of the simulation (module docstring)."""

    duration_s: float = 60.0
    rate_hz: float = 100.0
    rest_s: float = 3.0
    max_tilt_deg: float = 3.0
    window_s: float = 1.0
    gyro_turn_on_sigma: float = 0.01  # rad/s
    acc_z_turn_on_sigma: float = 0.1  # m/s^2
    unit_bias: tuple[float, ...] = (0.002, -0.003, 0.001, 0.05, -0.08, 0.1)
    coeff_per_degc: tuple[float, ...] = (6e-4, -5e-4, 4e-4, 0.01, -0.008, 0.012)
    reference_degc: float = 25.0
    ambient_degc: tuple[float, float] = (15.0, 35.0)
    rise_degc: tuple[float, float] = (3.0, 10.0)
    tau_s: float = 20.0
    gyro_noise: float = 2e-3  # rad/s per sample
    acc_noise: float = 2e-2  # m/s^2 per sample


def _motion(sim: RestSim, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Angular rate [N, 3] (rad/s, body) and world acceleration [N, 3] (m/s^2), zero during the rest."""
    fade = np.clip((t - sim.rest_s) / 1.0, 0.0, 1.0)[:, None] ** 2
    def waves(amp: float) -> np.ndarray:
        f = rng.uniform(0.1, 1.0, (4, 3))
        ph = rng.uniform(0, 2 * np.pi, (4, 3))
        a = rng.uniform(0.3, 1.0, (4, 3)) * amp / 2
        return (a[None] * np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None])).sum(1)
    return fade * waves(0.8), fade * waves(1.5)


def simulate_rest_sequence(sim: RestSim, seed: int) -> dict[str, np.ndarray]:
    """One sequence: ``t_ns`` [N], ``imu`` [N, 6], ``bias`` [N, 6], ``temperature_degc`` [N], the
    reference trajectory ``R`` [N, 3, 3], ``v``, ``p`` [N, 3] (module docstring)."""
    rng = np.random.default_rng(seed)
    n = int(round(sim.duration_s * sim.rate_hz)) + 1
    dt = 1.0 / sim.rate_hz
    t = np.arange(n) * dt
    t_ns = np.round(t * 1e9).astype(np.int64) + 10**9
    tilt = np.deg2rad(sim.max_tilt_deg) * rng.uniform(-1, 1, 2) / np.sqrt(2)
    R0 = so3_exp_np(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])) @ so3_exp_np(np.array([*tilt, 0.0]))
    omega, acc_w = _motion(sim, t, rng)
    g = np.asarray(DEFAULT_GRAVITY_MPS2, dtype=np.float64)
    dts = np.full((1, n - 1), dt)
    att = integrate_numpy(omega[None], np.zeros((1, n, 3)), dts, R0[None], np.zeros((1, 3)), np.zeros((1, 3)),
                          gravity_mps2=g, return_trajectory=True)
    R = att.R_traj[0]
    force = np.einsum("nji,nj->ni", R, acc_w - g)
    truth = integrate_numpy(omega[None], force[None], dts, R0[None], np.zeros((1, 3)), np.zeros((1, 3)),
                            gravity_mps2=g, return_trajectory=True)
    temp = rng.uniform(*sim.ambient_degc) + rng.uniform(*sim.rise_degc) * (1 - np.exp(-t / sim.tau_s))
    turn_on = np.zeros(6)
    turn_on[:3] = sim.gyro_turn_on_sigma * rng.standard_normal(3)
    turn_on[5] = sim.acc_z_turn_on_sigma * rng.standard_normal()
    bias = (turn_on + np.asarray(sim.unit_bias))[None] + np.asarray(sim.coeff_per_degc)[None] * (
        temp - sim.reference_degc)[:, None]
    noise = rng.standard_normal((n, 6)) * np.repeat([sim.gyro_noise, sim.acc_noise], 3)[None]
    imu = np.hstack([omega, force]) + bias + noise
    return {"t_ns": t_ns, "imu": imu, "bias": bias, "temperature_degc": temp,
            "R": truth.R_traj[0], "v": truth.v_traj[0], "p": truth.p_traj[0]}


def _windows(seq: dict[str, np.ndarray], name: str, split: Split, sim: RestSim) -> SequenceWindows:
    T = int(round(sim.window_s * sim.rate_hz)) + 1
    step = (T - 1) // 2
    starts = np.arange(0, len(seq["t_ns"]) - T + 1, step)
    idx = starts[:, None] + np.arange(T)[None]
    last = starts + T - 1
    bias = seq["bias"][idx]
    arrays = {"imu": seq["imu"][idx], "bias": bias, "bias_std": np.full_like(bias, 1e-4), "t_ns": seq["t_ns"][idx],
              "start_R": seq["R"][starts], "start_v": seq["v"][starts], "start_p": seq["p"][starts],
              "end_R": seq["R"][last], "end_v": seq["v"][last], "end_p": seq["p"][last],
              "temperature_degc": seq["temperature_degc"][idx]}
    info = {"rate_hz": sim.rate_hz, "gravity_mps2": list(DEFAULT_GRAVITY_MPS2), "simulated": "training.data.sim_context"}
    return SequenceWindows(name, split, arrays, info=info)


def write_rest_sim_dataset(out: str | Path, sim: RestSim = RestSim(), *, train: int = 12, val: int = 3,
                           test: int = 6, seed: int = 0) -> Path:
    """Write the dataset (``train`` / ``val`` / ``test`` sequences) and its ``context/`` to ``out``."""
    out = Path(out)
    plan = [(Split.TRAIN, train), (Split.VAL, val), (Split.TEST, test)]
    seqs: list[tuple[str, Split, dict[str, np.ndarray]]] = []
    k = 0
    for split, count in plan:
        for i in range(count):
            seqs.append((f"rest_{split.value}_{i:02d}", split, simulate_rest_sequence(sim, seed * 10_007 + k)))
            k += 1
    write_dataset((_windows(s, name, split, sim) for name, split, s in seqs), out,
                  config={"simulation": "training.data.sim_context", "seed": seed, "rate_hz": sim.rate_hz},
                  extra={"rate_hz": sim.rate_hz})
    with atomic_dir(out / CONTEXT_DIR) as tmp:
        for name, _, s in seqs:
            (tmp / name).mkdir()
            np.save(tmp / name / "imu.npy", s["imu"])
            np.save(tmp / name / "t_ns.npy", s["t_ns"])
            np.save(tmp / name / "temperature_degc.npy", s["temperature_degc"])
    return out
