"""Is EuRoC's V1_01 bias estimate consistent with its own static start? 

Kinematics only, no graph: with the EuRoC GT poses (IMU frame, IMU clock) the specific force
must satisfy ``f_k = R_k^T (a_k - g) + b_a`` (``a_k`` from the GT positions). The script prints

1. the constant-bias fit ``b_a`` + gravity tilt (|g| = 9.81) over the first 60 s and the whole
   sequence: EuRoC's ``b_a`` (a constant over the excerpt) is what a constant-bias model gives;
2. the local ``b_a`` of the static start (motors on, < 3 mm motion) with gravity along the Vicon z
   and along the fitted tilt, and its difference to EuRoC's value;
3. the residual EuRoC's own (attitude, b_a) leave at the static start: an unexplained horizontal
   specific force (a gravity tilt, mrad) and the drift it would integrate to in 3 s;
4. the spread of the local ``b_a`` over 5-s chunks (how far a sequence constant is from the
   local value anywhere in the recording).

Usage::

    .venv/bin/python benchmarks/recovery/v101_bias_consistency.py
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data")) / "euroc"
G = 9.81
STATIC_S = (0.3, 3.3)  # seconds after the first EuRoC GT stamp; the drone takes off at ~3.5-4 s


def _load(data: Path) -> dict:
    """IMU, EuRoC GT poses (IMU frame and clock) and EuRoC's estimate; GT kinematics per GT stamp."""
    imu = pd.read_csv(data / "V1_01_easy/mav0/imu0/data.csv").to_numpy()
    t_imu = imu[:, 0].astype(np.int64)
    gt = np.loadtxt(data / "V1_01_easy/ov_data/V1_01_easy_original.txt")
    t_gt = np.round(gt[:, 0] * 1e9).astype(np.int64)
    ref = pd.read_csv(data / "V1_01_easy_proto_excerpt/mav0/state_groundtruth_estimate0/data.csv").to_numpy()
    rot = Rotation.from_quat(gt[:, 4:8])  # TUM: qx qy qz qw
    dt = float(np.median(np.diff(t_gt))) / 1e9
    acc_w = savgol_filter(gt[:, 1:4], 41, 2, deriv=2, delta=dt, axis=0)  # 0.2 s local quadratic
    f = np.stack([np.interp(t_gt, t_imu, imu[:, 4 + c]) for c in range(3)], axis=1)
    t = (t_gt - int(ref[0, 0])) / 1e9
    inside = (t_gt > t_imu[0]) & (t_gt < t_imu[-1])
    return dict(imu=imu, t_imu=t_imu, gt=gt, t_gt=t_gt, ref=ref, rot=rot, dt=dt, acc_w=acc_w, f=f, t=t, inside=inside)


def static_start_check(data: Path = DATA) -> dict[str, np.ndarray]:
    """The numbers behind item 2: EuRoC's b_a and the local b_a of the static start (gravity along
    the Vicon z), and how far the GT moves there. Used by tests/recover/test_recovery_real.py."""
    d = _load(data)
    st = d["inside"] & (d["t"] >= STATIC_S[0]) & (d["t"] < STATIC_S[1])
    ba_local = (d["f"][st] - d["rot"][st].inv().apply(d["acc_w"][st] + np.array([0.0, 0.0, G]))).mean(axis=0)
    return {"t0_ns": np.array(int(d["ref"][0, 0])), "ba_euroc": d["ref"][0, 14:17], "ba_static_local": ba_local,
            "gt_motion_m": np.ptp(d["gt"][st, 1:4], axis=0).max()}


def main() -> None:
    d = _load(DATA)
    imu, t_imu, gt, t_gt, ref = d["imu"], d["t_imu"], d["gt"], d["t_gt"], d["ref"]
    bg_ref, ba_ref = ref[0, 11:14], ref[0, 14:17]
    rot, dt, acc_w, f, t = d["rot"], d["dt"], d["acc_w"], d["f"], d["t"]
    Rm = rot.as_matrix()
    sf_w = rot.apply(f) - acc_w  # = R b_a - g
    ok = d["inside"] & (t > 0.3) & (t < t[-1] - 0.3)

    def const_fit(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Least squares of R b_a - [gx, gy, -G] = sf_w: constant b_a, horizontal gravity."""
        A = np.concatenate([Rm[m], np.repeat(-np.eye(3)[None, :, :2], m.sum(), 0)], axis=2).reshape(-1, 5)
        y = (sf_w[m] + np.array([0.0, 0.0, -G])).reshape(-1)
        x = np.linalg.lstsq(A, y, rcond=None)[0]
        return x[:3], np.array([x[3], x[4], -G])

    def local_ba(m: np.ndarray, g: np.ndarray) -> np.ndarray:
        return np.einsum("kji,kj->ki", Rm[m], sf_w[m] + g).mean(axis=0)

    def tilt_mrad(g: np.ndarray) -> float:
        return float(1e3 * np.arccos(-g[2] / np.linalg.norm(g)))

    p = lambda v: np.array2string(np.asarray(v), precision=4, suppress_small=True)  # noqa: E731
    print(f"EuRoC b_a (excerpt, constant to {ref[:, 14:17].std(0).max():.1e}): {p(ba_ref)}")
    fits = {}
    for name, (a, b) in {"first 60 s": (0.0, 60.0), "whole sequence": (0.0, 1e9)}.items():
        ba, g = const_fit(ok & (t >= a) & (t < b))
        fits[name] = g
        print(f"constant b_a + tilt fit, {name:>14}: b_a {p(ba)}  (EuRoC - fit {p(ba_ref - ba)}), tilt {tilt_mrad(g):.2f} mrad")
    st = ok & (t >= STATIC_S[0]) & (t < STATIC_S[1])
    print(f"static start {STATIC_S} s: GT motion {1e3 * np.ptp(gt[st, 1:4], axis=0).max():.1f} mm, "
          f"attitude spread {np.degrees((rot[st].mean().inv() * rot[st]).magnitude().max()):.2f} deg")
    for name, g in (("Vicon z", np.array([0.0, 0.0, -G])), ("fitted tilt (whole sequence)", fits["whole sequence"])):
        ba = local_ba(st, g)
        print(f"  local b_a, gravity along {name:>28}: {p(ba)}  EuRoC - local {p(ba_ref - ba)}")
    resid = sf_w[st].mean(0) - rot[st].mean().apply(ba_ref) + np.array([0.0, 0.0, -G])  # = -g_implied + g
    g_impl = -(sf_w[st].mean(0) - rot[st].mean().apply(ba_ref))
    print(f"  EuRoC's (attitude, b_a) at the static start: horizontal residual {np.hypot(*resid[:2]):.4f} m/s^2 "
          f"(gravity tilt {tilt_mrad(g_impl):.2f} mrad, |g| {np.linalg.norm(g_impl):.4f}); over 3 s it integrates "
          f"to {0.5 * np.hypot(*resid[:2]) * 9:.2f} m while the GT moves < 3 mm")
    w = np.stack([np.interp(t_gt, t_imu, imu[:, 1 + c]) for c in range(3)], axis=1)
    rate_gt = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt
    bg_local = (w[:-1] - rate_gt)[st[:-1]].mean(0)
    print(f"  local gyro bias {p(bg_local)}  EuRoC - local {p(bg_ref - bg_local)}")
    chunks = np.array([local_ba(ok & (t >= s) & (t < s + 5.0), fits["whole sequence"])
                       for s in np.arange(0.3, t[ok][-1] - 5.0, 5.0)])
    print(f"local b_a over {len(chunks)} chunks of 5 s (fitted tilt): mean {p(chunks.mean(0))}, std {p(chunks.std(0))}, "
          f"range y {chunks[:, 1].min():.3f}..{chunks[:, 1].max():.3f}")


if __name__ == "__main__":
    main()
