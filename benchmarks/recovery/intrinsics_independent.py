"""The recovery on an uncalibrated MEMS IMU from the independent generator (tests/independent.py), with defaults.

    .venv/bin/python benchmarks/recovery/intrinsics_independent.py [--seeds 0 1 2 3] [--duration 120] [--bound]

Per seed: the clean sequence and the same one with intrinsic errors drawn at MEMS-like sizes
(``independent.draw_intrinsics``: gyro scale 0.5-1 %, 0.2-0.5 deg on every off-diagonal term of the
gyro matrix, its rotation part included, accelerometer scale 0.2-0.5 %, g-sensitivity up to 2e-4
rad/s per m/s^2 on each of the nine terms), both written as EuRoC folders, read back and recovered
with the default ``RecoveryConfig`` (intrinsics AUTO). Printed: per-axis bias RMSE, its ratio to the
clean recovery's (goal <= 2), per-axis NEES (goal: mean over seeds in [0.5, 2], no seed above 4),
and what ``recovery.json`` says was estimated and what the bias absorbed.

``--bound``: the intrinsics fit against the *true* trajectory and bias (no solve): each term's
sigma times the signal it multiplies is the least bias error a recovery can reach for it, also as a
ratio to the clean recovery's RMSE per axis (the gravity-axis terms: ``G [x,y,z]z`` for the gyro,
the accelerometer's ``[x,y,z]z``; without a calibration file's rotation the accelerometer's
``xz``/``yz``, its tilt, are as blind as its z scale).

When the first solve's accelerometer agrees with the calibration file's extrinsic rotation, the
fits take the file's rotation as the accelerometer's (``recovery.intrinsics.frame.rotation_prior``):
the tilt terms are estimated and only the z scale is left to the bias (``absorbed_by_bias``,
"not observable from this motion").
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import independent as ind  # noqa: E402

AXES = ("gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z")


def recovered(seed: int, duration_s: float, intrinsics: bool):
    """``(result, per-axis RMSE [6], per-axis NEES [6], seconds)`` of the default recovery of one sequence."""
    from pipeline.io import load_sequence
    from recovery.recover import recover

    seq = ind.make_sequence(duration_s, seed=seed, intrinsics=ind.draw_intrinsics(seed) if intrinsics else None)
    with tempfile.TemporaryDirectory() as tmp:
        loaded = load_sequence(ind.write_euroc(seq, Path(tmp) / f"seed{seed}"))
        t0 = time.perf_counter()
        res = recover(loaded)
        seconds = time.perf_counter() - t0
    fig = ind.recovery_figures(res, seq)
    return res, np.r_[fig.gyro_rmse_radps, fig.acc_rmse_mps2], fig.nees_per_axis, seconds


def _row(label: str, values: np.ndarray, fmt: str = "{:9.2e}") -> str:
    return f"  {label:26s}" + " ".join(fmt.format(v) for v in values)


def bound(seed: int, duration_s: float, clean_rmse: np.ndarray | None = None) -> None:
    """The fit against the true trajectory: sigma of each term x its signal (module docstring), and its ratio
    to ``clean_rmse`` [6] (the clean recovery's per-axis RMSE) when given."""
    from pipeline.types import ImuNoiseModel, ImuSeries
    from recovery.intrinsics.estimate import fit_intrinsics

    truth = ind.draw_intrinsics(seed)
    s = ind.make_sequence(duration_s, seed=seed, intrinsics=truth)
    k = np.arange(0, len(s.t_ns), int(s.rate_hz / 10))  # 10-Hz keyframes
    b = np.hstack([s.bias_gyro_radps, s.bias_acc_mps2])
    r = ind.REPORTED
    noise = ImuNoiseModel(r["gyro_noise_density"], 10 * r["gyro_random_walk"], r["acc_noise_density"], 10 * r["acc_random_walk"])
    fit = fit_intrinsics(ImuSeries(s.t_ns, s.gyro_radps, s.acc_mps2), s.t_ns[k], s.quat_wxyz[k], s.v_mps[k],
                         lambda t: np.stack([np.interp(t, s.t_ns, b[:, c]) for c in range(6)], axis=1),
                         ind.GRAVITY_MPS2, noise, g_sensitivity=True)
    f_z = float(np.mean(s.acc_true_mps2[:, 2]))
    print(f"[bound seed {seed}] fit against the true trajectory and bias ({duration_s:g} s), mean f_z {f_z:.2f} m/s^2:")
    print(f"  sigma acc scale zz {fit.sigma['acc_scale_misalignment'][2, 2]:.2e} -> acc z bias "
          f"{fit.sigma['acc_scale_misalignment'][2, 2] * f_z:.2e} m/s^2; sigma acc [x,y]z (tilt of the accelerometer "
          f"frame) {fit.sigma['acc_scale_misalignment'][0, 2]:.2e}, {fit.sigma['acc_scale_misalignment'][1, 2]:.2e} -> "
          f"acc x/y bias {fit.sigma['acc_scale_misalignment'][0, 2] * f_z:.2e}, "
          f"{fit.sigma['acc_scale_misalignment'][1, 2] * f_z:.2e} m/s^2")
    g = fit.sigma["gyro_g_sensitivity"][:, 2]
    print(f"  sigma g-sensitivity [x,y,z]z {np.array2string(g, formatter={'float': '{:.2e}'.format})} -> gyro bias "
          f"{np.array2string(g * f_z, formatter={'float': '{:.2e}'.format})} rad/s")
    if clean_rmse is not None:
        least = np.r_[g * f_z, fit.sigma["acc_scale_misalignment"][[0, 1, 2], 2] * f_z]
        print(_row("least error / clean RMSE", least / clean_rmse, "{:9.2f}"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--bound", action="store_true", help="also the fit against the true trajectory (no solve)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    ratios, nees_all = [], []
    for seed in args.seeds:
        _, clean_rmse, clean_nees, t_clean = recovered(seed, args.duration, intrinsics=False)
        res, rmse, nees, t_full = recovered(seed, args.duration, intrinsics=True)
        rep = res.report
        auto = rep.get("intrinsics_auto") or {}
        print(f"--- seed {seed}, {args.duration:g} s (clean {t_clean:.0f} s, intrinsic errors {t_full:.0f} s; "
              f"intrinsics {'estimated' if auto.get('estimated') else 'not estimated'} by AUTO)")
        print("  " + " " * 26 + " ".join(f"{a:>9s}" for a in AXES))
        print(_row("RMSE clean", clean_rmse))
        print(_row("NEES clean", clean_nees, "{:9.2f}"))
        print(_row("RMSE intrinsic errors", rmse))
        print(_row("ratio to clean (<= 2)", rmse / clean_rmse, "{:9.2f}"))
        print(_row("NEES (0.5..2)", nees, "{:9.2f}"))
        entry = rep.get("intrinsics") or {}
        absorbed = entry.get("absorbed_by_bias") or []
        print(f"  estimated: {len(entry.get('estimated') or [])} terms; the bias absorbed {len(absorbed)}: "
              + ", ".join(f"{e['term']} ({e['why'].split(' (')[0]})" for e in absorbed))
        print(f"  bias sigma added by the intrinsics, mean per axis: "
              f"{np.array2string(np.array(entry.get('bias_std_added_mean', [0.0] * 6)), formatter={'float': '{:.2e}'.format})}")
        ratios.append(rmse / clean_rmse)
        nees_all.append(nees)
        if args.bound:
            bound(seed, args.duration, clean_rmse)
    ratios, nees_all = np.array(ratios), np.array(nees_all)
    print(f"=== over seeds {args.seeds}")
    print("  " + " " * 26 + " ".join(f"{a:>9s}" for a in AXES))
    print(_row("RMSE ratio, mean (<= 2)", ratios.mean(0), "{:9.2f}"))
    print(_row("RMSE ratio, worst seed", ratios.max(0), "{:9.2f}"))
    print(_row("NEES mean (0.5..2)", nees_all.mean(0), "{:9.2f}"))
    print(_row("NEES worst seed (<= 4)", nees_all.max(0), "{:9.2f}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
