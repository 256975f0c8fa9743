"""The NEES a random-walk smoother's honest sigma gives when the bias does not walk at all.

Usage::

    .venv/bin/python benchmarks/recovery/constant_bias_nees.py [--duration 120] [--keyframe-hz 10]

The recovery models the bias as a random walk, its strength searched over ``random_walk_scales``
times the calibration's (smallest 0.1x). Its sigma is honest for a bias drawn from such a walk; a
unit whose bias is exactly constant (the rig benchmark's ``mocap_gm`` scenario) is one draw the walk
makes with probability zero, and its errors are only the noise's, not the walk's. For one axis seen
through white noise, the smoother's estimate is ``x = K y`` with ``K = P R^-1`` and its posterior
covariance

    P = (J + R^-1)^-1,   J = D^T D / (q^2 dt)    (D: first differences; q: walk, density units)

so with a constant truth the error ``K v`` (the truth passes through: ``K 1 = 1``) has covariance
``P R^-1 P``, and the expected NEES per keyframe is ``(P R^-1 P)_kk / P_kk``. In steady state (walk
time constant ``density / q`` much shorter than the recording) this is exactly 1/2: the smoother's
impulse response is ``exp(-|t| / tau) / (2 tau)`` with ``tau = density / q``, whose noise passes
``density^2 / (4 tau)`` while the posterior variance is ``density^2 / (2 tau)``.

Printed per sensor (the calibration's densities and walks, :class:`pipeline.types.ImuNoiseModel`)
and walk scale: the walk's time constant, the expected NEES of a constant bias, and the sigma. The
scalar model leaves out the pose noise, the attitude and the other axes, so it is the smoother's part
of the figure, not a prediction of a recovery's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from pipeline.types import ImuNoiseModel  # noqa: E402
from recovery.config import RecoveryConfig  # noqa: E402


def constant_bias_nees(density: float, walk: float, duration_s: float, dt_s: float) -> tuple[float, float]:
    """``(mean over keyframes of the expected NEES, RMS posterior sigma)`` of a constant bias under a
    random-walk smoother (module docstring); ``density`` and ``walk`` in the sensor's units."""
    n = int(round(duration_s / dt_s)) + 1
    r_inv = dt_s / density**2  # y_k = b_k + v_k, var(v) = density^2 / dt
    D = np.diff(np.eye(n), axis=0)
    P = np.linalg.inv(D.T @ D / (walk**2 * dt_s) + r_inv * np.eye(n))
    err_var = np.einsum("ij,ij->i", P, P) * r_inv  # diag(P R^-1 P), P symmetric
    p = np.diag(P)
    return float(np.mean(err_var / p)), float(np.sqrt(p.mean()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=120.0, help="recording length, s")
    ap.add_argument("--keyframe-hz", type=float, default=10.0, help="keyframes per second")
    args = ap.parse_args(argv)
    dt = 1.0 / args.keyframe_hz
    steady, _ = constant_bias_nees(1.0, 0.5, 100.0, 0.02)  # tau = 2 s: >> dt, << the span
    print(f"steady state (tau 2 s, 100 s, dt 0.02 s): expected NEES {steady:.3f} (closed form 0.5)")
    if abs(steady - 0.5) > 0.01:
        print("the steady-state figure is off its closed form: the computation is wrong")
        return 1
    cal = ImuNoiseModel()
    print(f"{args.duration:g} s at {args.keyframe_hz:g} keyframes/s; the calibration's densities and walks")
    print(f"{'sensor':7s}{'walk scale':>11s}{'tau (s)':>10s}{'expected NEES':>15s}{'sigma':>11s}")
    for sensor, density, walk in (("gyro", cal.gyro_noise_density, cal.gyro_random_walk),
                                  ("acc", cal.acc_noise_density, cal.acc_random_walk)):
        for scale in RecoveryConfig().random_walk_scales:
            nees, sigma = constant_bias_nees(density, walk * scale, args.duration, dt)
            print(f"{sensor:7s}{scale:11g}{density / (walk * scale):10.3g}{nees:15.3f}{sigma:11.3e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
