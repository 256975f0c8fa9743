"""Small window datasets with a known conditional bias distribution, written in the real format.

Every window's IMU readings carry a condition ``c`` (uniform in [-1, 1]) on every gyro and
accelerometer channel plus white noise; the bias of each channel is constant over the window and
drawn given ``c``:

* ``GAUSSIAN``: ``b = a c + s z``, ``z ~ N(0, 1)``;
* ``BIMODAL``: ``b = a c + m`` with ``m = +d`` (probability ``p_plus``) or ``-d``;
* ``LINEAR``: ``b = a c`` (deterministic; for training-infrastructure tests).

The reference start/end states are consistent with the readings: the end state is the start
state integrated with ``imu - bias`` (so the indirect loss can learn the bias too). Temperature
(``temperature_degc`` [T] per window) is written when asked, as ``20 + 5 c``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.geometry.integration import integrate_numpy
from training.data.dataset import SequenceWindows, Split, write_dataset

GRAVITY = (0.0, 0.0, -9.81)


class Kind(str, enum.Enum):
    GAUSSIAN = "gaussian"
    BIMODAL = "bimodal"
    LINEAR = "linear"


@dataclass(frozen=True)
class Toy:
    kind: Kind = Kind.LINEAR
    samples: int = 16  # T
    rate_hz: float = 100.0
    slope: float = 0.5  # a
    std: float = 0.2  # s (GAUSSIAN)
    offset: float = 0.6  # d (BIMODAL)
    p_plus: float = 0.3
    imu_noise: float = 0.02
    shared: bool = True  # one draw per window for all 6 channels (else one per channel)

    def bias(self, c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Bias [W, 6] (constant per window) for conditions ``c`` [W]."""
        base = self.slope * c[:, None] * np.ones((1, 6))
        shape = (len(c), 1) if self.shared else base.shape
        if self.kind is Kind.GAUSSIAN:
            return base + self.std * rng.standard_normal(shape)
        if self.kind is Kind.BIMODAL:
            return base + np.where(rng.random(shape) < self.p_plus, self.offset, -self.offset)
        return base


def toy_sequence(toy: Toy, name: str, split: Split, windows: int, seed: int,
                 temperature: bool = False) -> SequenceWindows:
    """One sequence of ``windows`` toy windows."""
    rng = np.random.default_rng(seed)
    T = toy.samples
    c = rng.uniform(-1.0, 1.0, windows)
    imu = c[:, None, None] + toy.imu_noise * rng.standard_normal((windows, T, 6))
    imu[..., 5] += 9.81  # a level IMU at rest-ish: gravity on acc z
    bias = np.repeat(toy.bias(c, rng)[:, None, :], T, axis=1)
    t_ns = (np.arange(T)[None, :] * round(1e9 / toy.rate_hz) + (np.arange(windows) * 10**10)[:, None]).astype(np.int64)
    start_R = np.repeat(np.eye(3)[None], windows, axis=0)
    start_v = 0.1 * rng.standard_normal((windows, 3))
    start_p = rng.standard_normal((windows, 3))
    end = integrate_numpy(imu[..., :3], imu[..., 3:], np.diff(t_ns, axis=1) * 1e-9, start_R, start_v, start_p,
                          gravity_mps2=GRAVITY, bias_gyro_radps=bias[..., :3], bias_acc_mps2=bias[..., 3:])
    arrays = {"imu": imu, "bias": bias, "bias_std": np.full_like(bias, 1e-3), "t_ns": t_ns,
              "start_R": start_R, "start_v": start_v, "start_p": start_p,
              "end_R": end.R, "end_v": end.v, "end_p": end.p}
    if temperature:
        arrays["temperature_degc"] = np.repeat((20.0 + 5.0 * c)[:, None], T, axis=1)
    info = {"rate_hz": toy.rate_hz, "gravity_mps2": list(GRAVITY), "condition": c.tolist()}
    return SequenceWindows(name, split, arrays, info=info)


def write_toy_dataset(out: Path, toy: Toy = Toy(), *, train: int = 256, val: int = 64, test: int = 64,
                      seed: int = 0, temperature: bool = False) -> Path:
    """Write a toy dataset (one sequence per split) to ``out`` and return it."""
    seqs = [toy_sequence(toy, f"toy_{split.value}", split, n, seed + i, temperature)
            for i, (split, n) in enumerate(((Split.TRAIN, train), (Split.VAL, val), (Split.TEST, test))) if n]
    write_dataset(seqs, out, config={"toy": toy.kind.value, "samples": toy.samples}, extra={"rate_hz": toy.rate_hz})
    return out


@pytest.fixture
def one_torch_thread():
    """Run a test on one torch thread (deterministic and not oversubscribing the cores)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
