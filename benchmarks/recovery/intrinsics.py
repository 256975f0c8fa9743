"""IMU intrinsics estimated around the bias recovery (recovery.intrinsics.estimate): the figures of its acceptance.

    .venv/bin/python benchmarks/recovery/intrinsics.py [--duration 120] [--preset aggressive_drone] [--seeds 0 1 2]
                                              [--skip-real] [--skip-sim]

1. Simulated sequence with 1 % gyro scale, 0.5 deg gyro misalignment, 0.5 % accelerometer scale and
   a gyro g-sensitivity of 1e-3 rad/s per m/s^2 (readings rewritten from the simulator's, which has
   none): each term against the truth (within 3 sigma? within 10 % of its size?), and the bias RMSE
   against the same sequence without intrinsic errors (goal: within 1.1x).
2. The same sequence without intrinsic errors, intrinsics on vs off (the cost of turning them on).
3. Real EuRoC V1_01 (IMU + ground-truth poses): the gyro random walk the evidence search picks, and
   the correlation of each axis of the recovered gyro bias with each axis of the angular rate,
   intrinsics off vs on (goals: <= 10x the datasheet, every |correlation| < 0.2).
4. Where V1_01's excess gyro walk comes from (recovery.intrinsics.gyro_consistency), against EuRoC's
   ground-truth poses and OpenVINS's re-estimated poses of the same IMU: the coupling of
   ``gyro - reference rate`` to the rate by frequency band (an intrinsic error has the same gain
   in every band); the walk the evidence search picks after the gyro is corrected by the
   misalignment that best fits the recovered bias; and the per-axis maximum-likelihood walk with
   the reference's attitude error modelled as white, or as white plus Gauss-Markov.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # the project's packages before this folder's scripts (benchmarks/recovery/recovery.py)

from pipeline.sim import SimConfig, simulate  # noqa: E402
from pipeline.sim.config import MotionConfig, PoseStreamConfig  # noqa: E402
from recovery.config import IntrinsicsMode, RecoveryConfig  # noqa: E402
from recovery.recover import recover  # noqa: E402

SHARED = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data"))


def truth_intrinsics() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The acceptance case: M_g (1 % scales, 0.5 deg misalignments), M_a (0.5 % scales), G (1e-3)."""
    M_g = np.diag([1.01, 0.99, 1.01])
    M_g[0, 1], M_g[2, 0] = np.radians(0.5), -np.radians(0.5)
    M_a = np.diag([1.005, 0.995, 1.005])
    G = np.zeros((3, 3))
    G[0, 2], G[1, 0] = 1e-3, -1e-3
    return M_g, M_a, G


def full_intrinsics() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every term at once: M_g with 1 % scales and 0.5 deg on every off-diagonal term (not symmetric, so
    its rotation part too), M_a with 0.5 % scales, and a full 3x3 G of 1e-3 rad/s per m/s^2."""
    M_g = np.diag([1.01, 0.99, 1.01]) + np.radians(0.5) * np.array([[0, 1, -1], [-1, 0, 1], [1, -1, 0]], float)
    M_a = np.diag([1.005, 0.995, 1.005])
    G = 1e-3 * np.array([[1, -1, 1], [-1, 1, -1], [1, 1, -1]], float)
    return M_g, M_a, G


def with_intrinsics(sim, M_g: np.ndarray, M_a: np.ndarray, G: np.ndarray):
    """The simulated sequence with readings ``gyro = M_g w + G f + b_g``, ``acc = M_a f + b_a``."""
    imu, tr = sim.sequence.imu, sim.truth
    f = imu.acc_mps2 - tr.bias_acc_mps2
    gyro = (imu.gyro_radps - tr.bias_gyro_radps) @ M_g.T + f @ G.T + tr.bias_gyro_radps
    acc = f @ M_a.T + tr.bias_acc_mps2
    return dataclasses.replace(sim.sequence, imu=dataclasses.replace(imu, gyro_radps=gyro, acc_mps2=acc))


def bias_rmse(result, truth) -> np.ndarray:
    true = np.hstack([truth.bias_gyro_radps, truth.bias_acc_mps2])
    at = np.stack([np.interp(result.t_ns, truth.t_ns, true[:, c]) for c in range(6)], axis=1)
    est = np.hstack([result.bias_gyro_radps, result.bias_acc_mps2])
    return np.sqrt(np.mean((est - at) ** 2, axis=0))


def nees(result, truth) -> np.ndarray:
    """Per-axis mean of (error / reported sigma)^2, [6]."""
    true = np.hstack([truth.bias_gyro_radps, truth.bias_acc_mps2])
    at = np.stack([np.interp(result.t_ns, truth.t_ns, true[:, c]) for c in range(6)], axis=1)
    err = np.hstack([result.bias_gyro_radps, result.bias_acc_mps2]) - at
    std = np.hstack([result.bias_gyro_std_radps, result.bias_acc_std_mps2])
    return np.mean((err / std) ** 2, axis=0)


def simulated(duration_s: float, preset: str, seed: int = 0) -> None:
    print(f"--- simulated {preset}, {duration_s:g} s, seed {seed}")
    sim = simulate(SimConfig(duration_s=duration_s, seed=seed, motion=MotionConfig(preset=preset),
                             poses=PoseStreamConfig(extrinsic_known=True)))
    M_g, M_a, G = truth_intrinsics()
    on = RecoveryConfig(intrinsics=IntrinsicsMode.WITH_G_SENSITIVITY)
    runs = {}
    off = RecoveryConfig(intrinsics=IntrinsicsMode.OFF)
    bad = with_intrinsics(sim, M_g, M_a, G)
    for name, seq, cfg in (("clean, off", sim.sequence, off), ("clean, on", sim.sequence, on),
                           ("clean, auto", sim.sequence, RecoveryConfig()),
                           ("intrinsic errors, off", bad, off), ("intrinsic errors, on", bad, on),
                           ("intrinsic errors, auto", bad, RecoveryConfig())):
        t0 = time.perf_counter()
        runs[name] = recover(seq, config=cfg)
        rmse = bias_rmse(runs[name], sim.truth)
        auto = runs[name].report.get("intrinsics_auto")
        if auto is not None:
            print(f"  auto: intrinsics {'estimated' if auto['estimated'] else 'not estimated'} "
                  f"(coupling {auto['coupling']})")
        print(f"{name:22s} bias RMSE gyro {np.array2string(rmse[:3], formatter={'float': '{:.3g}'.format})} rad/s, "
              f"acc {np.array2string(rmse[3:], formatter={'float': '{:.3g}'.format})} m/s^2 "
              f"({time.perf_counter() - t0:.1f} s)")
    base = bias_rmse(runs["clean, off"], sim.truth)
    for name in ("clean, off", "intrinsic errors, on"):
        print(f"NEES per axis, {name} (gyro xyz, acc xyz): {np.array2string(nees(runs[name], sim.truth), precision=2)} "
              "(target 0.5..2)")
    full = recover(with_intrinsics(sim, *full_intrinsics()), config=on)
    print(f"NEES per axis, every intrinsic term (full_intrinsics), on: "
          f"{np.array2string(nees(full, sim.truth), precision=2)} (target 0.5..2); RMSE ratio to clean "
          f"{np.array2string(bias_rmse(full, sim.truth) / bias_rmse(runs['clean, off'], sim.truth), precision=3)}")
    print("RMSE ratio, intrinsic errors + estimation / clean:",
          np.array2string(bias_rmse(runs["intrinsic errors, on"], sim.truth) / base, precision=3), "(goal <= 1.1)")
    print("RMSE ratio, clean + estimation / clean:",
          np.array2string(bias_rmse(runs["clean, on"], sim.truth) / base, precision=2), "(cost of turning it on)")
    print("RMSE ratio, auto / clean: clean", np.array2string(bias_rmse(runs["clean, auto"], sim.truth) / base, precision=3),
          "intrinsic errors", np.array2string(bias_rmse(runs["intrinsic errors, auto"], sim.truth) / base, precision=3))
    rep = runs["intrinsic errors, on"].report["intrinsics"]
    print(f"rounds: {rep['rounds']}; bias sigma widened by the terms' uncertainty, mean per axis "
          f"{np.array2string(np.array(rep['bias_std_inflation_mean']), precision=3)}; dropped after the last round "
          f"(within 3 sigma of zero): {', '.join(rep.get('dropped_at_end') or []) or 'none'}")
    for group, est, true in (("gyro_scale_misalignment", np.array(rep["gyro_matrix"]) - np.eye(3), M_g - np.eye(3)),
                             ("acc_scale_misalignment", np.array(rep["acc_matrix"]) - np.eye(3), M_a - np.eye(3)),
                             ("gyro_g_sensitivity", np.array(rep["gyro_g_sensitivity"]), G)):
        sig = np.array(rep["sigma"][group], dtype=float)
        for r, c in zip(*np.nonzero(true)):
            e, t, s = est[r, c], true[r, c], sig[r, c]
            print(f"  {group}[{'xyz'[r]}{'xyz'[c]}]: {e:+.5f} +- {s:.5f} (truth {t:+.5f}): "
                  f"{abs(e - t) / s:.1f} sigma, {100 * abs(e - t) / abs(t):.1f} % of its size")


V1_01 = SHARED / "euroc" / "V1_01_easy"


def load_v1_01():
    """V1_01's IMU (and its sensor.yaml calibration) with EuRoC's ground-truth poses (stream
    ``V1_01_easy_original``) and OpenVINS's re-estimated ones (``V1_01_easy``); None without the data."""
    if not V1_01.is_dir():
        print(f"V1_01: skipped ({V1_01} not found)")
        return None
    from pipeline.io import load_sequence

    return load_sequence(V1_01, extra_poses=[f"{V1_01 / 'ov_data' / 'V1_01_easy_original.txt'}:ground_truth",
                                             f"{V1_01 / 'ov_data' / 'V1_01_easy.csv'}:ground_truth"])


def _rate_at(res, imu) -> np.ndarray:
    """The gyro's rate at the recovery's keyframes, [K, 3]."""
    return np.stack([np.interp(res.t_ns, imu.t_ns, imu.gyro_radps[:, c]) for c in range(3)], axis=1)


def v1_01(seq) -> None:
    for mode in (IntrinsicsMode.OFF, IntrinsicsMode.WITH_G_SENSITIVITY):
        t0 = time.perf_counter()
        res = recover(seq, pose_stream="V1_01_easy_original", config=RecoveryConfig(intrinsics=mode))
        rate = _rate_at(res, seq.imu)
        # every axis of the bias against every axis of the rate: a misalignment shows off the diagonal
        corr = np.array([[np.corrcoef(res.bias_gyro_radps[:, r], rate[:, c])[0, 1] for c in range(3)]
                         for r in range(3)])
        worst = np.unravel_index(np.argmax(np.abs(corr)), corr.shape)
        noise = res.report["noise"]
        print(f"V1_01 intrinsics {mode.value:18s}: gyro random walk {noise['gyro_random_walk_scale']:.3g}x the datasheet "
              f"(goal <= 10x), acc {noise['acc_random_walk_scale']:.3g}x; corr(gyro bias, rate) same axis x/y/z "
              f"{', '.join(f'{c:+.2f}' for c in np.diag(corr))}, largest over all axis pairs {corr[worst]:+.2f} "
              f"(bias {'xyz'[worst[0]]} vs rate {'xyz'[worst[1]]}; goal |.| < 0.2) ({time.perf_counter() - t0:.0f} s)")
        print("  corr(gyro bias row, rate column):", np.array2string(corr, precision=2).replace("\n", ""))
        if "intrinsics" in res.report:
            rep = res.report["intrinsics"]
            print("  M_g - I:", np.array2string(np.array(rep["gyro_matrix"]) - np.eye(3), precision=4))
            print("  M_a - I:", np.array2string(np.array(rep["acc_matrix"]) - np.eye(3), precision=4))


def _recovered_walk(seq, stream: str, gyro_radps: np.ndarray | None = None):
    """``recover`` from ``stream`` (the gyro replaced by ``gyro_radps`` if given)."""
    if gyro_radps is not None:
        seq = dataclasses.replace(seq, imu=dataclasses.replace(seq.imu, gyro_radps=gyro_radps))
    return recover(seq, pose_stream=stream, config=RecoveryConfig(intrinsics=IntrinsicsMode.OFF))


def v1_01_reference(seq) -> None:
    from recovery.intrinsics.gyro_consistency import attitude_increments, fit_walk, rate_coupling

    cal = seq.calibration  # sensor.yaml's datasheet values
    for stream, label in (("V1_01_easy_original", "EuRoC ground truth"), ("V1_01_easy", "OpenVINS")):
        rc = rate_coupling(seq.imu, seq.poses[stream])
        b, r, c = rc.strongest()
        bands = ", ".join(f"{lo:g}-{hi:g} Hz {g:+.4f} ({h:.2f}, {n:.2f} needed)" for (lo, hi), g, h, n in
                          zip(rc.bands_hz, rc.gain[:, r, c], rc.coherence[:, r], rc.coherence_needed))
        print(f"V1_01 vs {label}: {rc.kind().value} coupling; gyro {'xyz'[r]} <- rate {'xyz'[c]}, gain (coherence of "
              f"gyro {'xyz'[r]}) by band: {bands}")
        print(f"  {rc.sentence()}")
        res = _recovered_walk(seq, stream)
        rate = _rate_at(res, seq.imu)
        X = np.c_[rate, np.ones(len(rate))]
        S = np.linalg.lstsq(X, res.bias_gyro_radps, rcond=None)[0][:3].T  # bias = S omega + b0
        fixed = _recovered_walk(seq, stream, seq.imu.gyro_radps - seq.imu.gyro_radps @ S.T)
        print(f"  evidence walk {res.report['noise']['gyro_random_walk_scale']:.3g}x the datasheet; with the gyro "
              f"corrected by the misalignment fitted to its bias (largest term {S.flat[np.argmax(np.abs(S))]:+.4f}) "
              f"{fixed.report['noise']['gyro_random_walk_scale']:.3g}x (an intrinsic error would have dropped)")
        inc = attitude_increments(seq.imu, seq.poses[stream], interval_s=0.1)
        for axis in range(3):
            white = fit_walk(inc[:, axis], 0.1, cal.gyro_noise_density)
            gm = fit_walk(inc[:, axis], 0.1, cal.gyro_noise_density, gauss_markov=True)
            gm_text = (f"{1e3 * gm.gm_sigma_rad:.2f} mrad, tau {gm.gm_tau_s:.2f} s" if gm.gm_sigma_rad > 1e-5
                       else "fitted to zero")
            print(f"  axis {'xyz'[axis]}: maximum-likelihood walk {white.random_walk / cal.gyro_random_walk:.0f}x "
                  f"the datasheet (white reference error {1e3 * white.white_rad:.3f} mrad); with a Gauss-Markov "
                  f"reference error {gm.random_walk / cal.gyro_random_walk:.0f}x ({gm_text}; log-likelihood "
                  f"{gm.log_likelihood - white.log_likelihood:+.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--preset", default="aggressive_drone")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="simulation seeds (the acceptance case: 0)")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-sim", action="store_true", help="only the real V1_01 figures")
    args = ap.parse_args()
    if not args.skip_sim:
        for seed in args.seeds:
            simulated(args.duration, args.preset, seed)
    seq = None if args.skip_real else load_v1_01()
    if seq is not None:
        v1_01(seq)
        v1_01_reference(seq)


if __name__ == "__main__":
    main()
