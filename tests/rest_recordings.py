"""Recordings that open with a rest, with white noise away from the EuRoC datasheet's, from two
generators: the project's simulator (``pipeline.sim``, ``motion.rest_s``) and the independent one
(``independent.py``, written from the equations). Shared by the noise-from-data test and benchmark."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from independent import LissajousMotion, RestThenMotion, make_sequence, write_euroc

#: White noise a few times the EuRoC datasheet's (1.6968e-4, 2.0e-3), so that borrowed values show.
GYRO_DENSITY, ACC_DENSITY = 5.0e-4, 6.0e-3
DURATION_S, REST_S = 50.0, 15.0


def simulated(root: Path, seed: int = 3, rest_s: float = REST_S) -> Path:
    """A EuRoC-layout recording from the project's simulator at ``root`` (``rest_s`` 0: it never rests)."""
    from pipeline.sim.config import SimConfig
    from pipeline.sim.simulator import simulate
    from pipeline.sim.writer import write_simulation

    cfg = SimConfig.from_dict({"name": "rest_sim", "duration_s": DURATION_S, "seed": seed, "motion": {"rest_s": rest_s},
                               "imu": {"gyro_noise_density": GYRO_DENSITY, "acc_noise_density": ACC_DENSITY,
                                       "reported_gyro_noise_density": GYRO_DENSITY,
                                       "reported_acc_noise_density": ACC_DENSITY}})
    write_simulation(simulate(cfg), root)
    return root


def independent(root: Path, seed: int = 4, rest_s: float = REST_S) -> Path:
    """A EuRoC-layout recording from the independent generator at ``root`` (``rest_s`` 0: it never rests)."""
    motion = RestThenMotion(LissajousMotion(), rest_s=rest_s) if rest_s > 0 else LissajousMotion()
    seq = make_sequence(DURATION_S, seed=seed, motion=motion,
                        gyro_noise_density=GYRO_DENSITY, acc_noise_density=ACC_DENSITY)
    write_euroc(seq, root, with_ground_truth=True)
    return root


def bias_agreement(first: Path, second: Path) -> np.ndarray:
    """RMS over the second recovery's keyframes (inside the first's span; keyframe stamps follow each
    clock offset) of the bias difference in the two recoveries' combined sigma, [6]."""
    from recovery.outputs import RecoveryOutputs

    b1, b2 = RecoveryOutputs.read(first).bias, RecoveryOutputs.read(second).bias
    inside = (b2.t_ns >= b1.t_ns[0]) & (b2.t_ns <= b1.t_ns[-1])
    at, std = (np.column_stack([np.interp(b2.t_ns[inside], b1.t_ns, x[:, c]) for c in range(6)])
               for x in (b1.bias, b1.std))
    z = (b2.bias[inside] - at) / np.hypot(b2.std[inside], std)
    return np.sqrt(np.mean(z**2, axis=0))
