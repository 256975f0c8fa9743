"""Acceptance benchmark of bias recovery (prints every figure; exit 0 even when a target is missed).

Usage::

    .venv/bin/python benchmarks/recovery/recovery.py                 # all cases except the 1-hour run
    .venv/bin/python benchmarks/recovery/recovery.py --only clean hard
    .venv/bin/python benchmarks/recovery/recovery.py --long          # also 1 hour of 200-Hz IMU (slow)

Cases:
    clean  simulated 120 s, known extrinsic, no clock offset, EuRoC-like IMU noise, bias random
           walk 10x datasheet + temperature term, 100-Hz mocap 0.5 mm / 0.5 mrad:
           per-axis RMSE <= 1.6e-4 rad/s and <= 4.5e-3 m/s^2, NEES in [0.5, 2].
    hard   + unknown 15 deg / 10 cm extrinsic, 12 ms clock offset, 4 dropouts <= 1.5 s, 20 outliers
           of 10 cm: offset within 1 ms, extrinsic within 0.5 deg / 1 cm, RMSE within 1.5x of clean,
           NEES 0.5..2 on every axis (the sigmas include the estimated calibration's uncertainty),
           for each of ``--seeds`` (default 0 1 2).
    v101   EuRoC V1_01 IMU + EuRoC GT poses (TUM, IMU frame, IMU clock): first 5 s vs EuRoC's own
           bias estimate, within 2e-3 rad/s and 0.08 m/s^2 per axis.
    mh01   EuRoC MH_01 IMU + raw Leica (lever arm from sensor.yaml, offset estimated) vs the
           recovery from the GT poses: >= 95% of keyframes within combined 3 sigma.
    speed  180 s of 200-Hz IMU + 100-Hz mocap, read -> written (store -> recovery folder) in a
           child process: seconds, peak RSS, x real time; the default (every pose sample,
           fused into 10-Hz keyframes), 20-Hz keyframes without fusion (samples between them
           dropped) and every sample its own keyframe (1 hour with --long). The machine is shared: timings vary with its load; the
           CPU seconds (process time, imports included) are steadier than the wall clock.
           ``--long`` adds 1 hour (goal: <= 2 GB peak RSS, time linear in duration).
    peer   the same 180 s: the default ``recover`` (offset, noise and gravity estimated, marginals
           on) against :func:`plain_gtsam_batch`, a plain GTSAM batch over the same 10-Hz keyframes
           with the extrinsic, clock offset, noise and gravity given (CombinedImuFactor,
           LevenbergMarquardtOptimizer, gtsam.Marginals for the bias std), both timed in one child
           process on one loaded sequence (9 back-to-back pairs in alternating order, imports and
           reading excluded), and as whole processes the way a user runs them (start, imports, read,
           solve, write: the ``speed`` child against the peer writing a CSV; CPU from the children's
           rusage). Goal: ratio default / peer <= 1.5, as the median of the pairs' CPU-second
           ratios (a shared machine's speed drifts between runs; the pairs see the same stretch),
           with the best-of-9 wall-clock and CPU ratios beside it. Also both tracks' RMSE and NEES
           against the truth.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
DATA = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data"))


def _config(**kw):
    """RecoveryConfig with the --config overrides (JSON object) applied on top of ``kw``."""
    from recovery.config import RecoveryConfig

    return RecoveryConfig.from_dict({**json.loads(os.environ.get("BIASGT_BENCH_CONFIG", "{}") or "{}"), **kw})


def _errors(res, truth):
    tb = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_gyro_radps[:, c]) for c in range(3)], 1)
    ta = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_acc_mps2[:, c]) for c in range(3)], 1)
    return res.bias_gyro_radps - tb, res.bias_acc_mps2 - ta


def _sim(duration_s, seed=0, **poses):
    from pipeline.sim import simulate
    from pipeline.sim.config import PoseStreamConfig, SimConfig

    return simulate(SimConfig(duration_s=duration_s, seed=seed, poses=PoseStreamConfig(**poses)))


def _mark(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def case_sim(hard: bool, clean_rmse=None, seed: int = 0):
    from recovery.recover import recover

    if hard:
        sim = _sim(120.0, seed, extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.10, clock_offset_s=0.012,
                   dropouts=4, dropout_max_s=1.5, outliers=20, outlier_offset_m=0.1)
    else:
        sim = _sim(120.0, extrinsic_known=True)
    t0 = time.perf_counter()
    res = recover(sim.sequence, config=_config())
    dt = time.perf_counter() - t0
    eg, ea = _errors(res, sim.truth)
    rg, ra = np.sqrt((eg**2).mean(0)), np.sqrt((ea**2).mean(0))
    from recovery.noise.bounds import bias_rmse_floor

    imu_cfg, pose_cfg = sim.config.imu, sim.config.poses
    floor_g = bias_rmse_floor(imu_cfg.gyro_noise_density, imu_cfg.gyro_random_walk, pose_cfg.rotation_noise_rad,
                              pose_cfg.rate_hz, 1)
    floor_a = bias_rmse_floor(imu_cfg.acc_noise_density, imu_cfg.acc_random_walk, pose_cfg.position_noise_m,
                              pose_cfg.rate_hz, 2)
    nees_g = ((eg / res.bias_gyro_std_radps) ** 2).mean()
    nees_a = ((ea / res.bias_acc_std_mps2) ** 2).mean()
    rep = res.report
    name = f"hard seed {seed}" if hard else "clean"
    print(f"[{name}] {rep['keyframes']} keyframes, runtime {dt:.1f} s, timings {json.dumps(rep['timings_s'])}")
    print(f"[{name}] gyro RMSE per axis {np.array2string(rg, precision=6)} rad/s"
          + ("" if hard else f"  (target <= 1.6e-4: {_mark(bool((rg <= 1.6e-4).all()))})"))
    print(f"[{name}] acc  RMSE per axis {np.array2string(ra, precision=5)} m/s^2"
          + ("" if hard else f"  (target <= 4.5e-3: {_mark(bool((ra <= 4.5e-3).all()))})"))
    print(f"[{name}] optimal-smoother floor for this noise (recovery.noise.bounds): gyro {floor_g:.3g} rad/s, acc "
          f"{floor_a:.3g} m/s^2; RMSE / floor: gyro {(rg / floor_g).max():.2f}, acc {(ra / floor_a).max():.2f} "
          f"(target about 1.3x the floor: {_mark(bool((rg <= 1.3 * floor_g).all() and (ra <= 1.3 * floor_a).all()))}"
          f"; the 4.5e-3 acc target is {(4.5e-3 / floor_a):.2f}x the floor)")
    print(f"[{name}] mean reported std gyro {res.bias_gyro_std_radps.mean():.3g} rad/s, acc "
          f"{res.bias_acc_std_mps2.mean():.3g} m/s^2 (the model's own accuracy bound for this noise)")
    nees_axes = np.concatenate([((eg / res.bias_gyro_std_radps) ** 2).mean(0), ((ea / res.bias_acc_std_mps2) ** 2).mean(0)])
    print(f"[{name}] NEES per DoF gyro {nees_g:.2f}, acc {nees_a:.2f}; per axis (gyro xyz, acc xyz) "
          f"{np.array2string(nees_axes, precision=2)} (target 0.5..2 on every axis: "
          f"{_mark(bool(((nees_axes >= 0.5) & (nees_axes <= 2)).all()))})")
    cal = rep["calibration_uncertainty"]
    if cal["included_in_bias_std"]:
        print(f"[{name}] sigmas include the calibration's uncertainty ({', '.join(cal['parameters'])}): std "
              f"inflation per axis mean {np.array2string(np.array(cal['std_inflation_mean']), precision=3)}, max "
              f"{np.array2string(np.array(cal['std_inflation_max']), precision=3)}")
    n = rep["noise"]
    print(f"[{name}] noise chosen: gyro rw x{n['gyro_random_walk_scale']:.3g}, acc rw x{n['acc_random_walk_scale']:.3g}, "
          f"pose sigma {n['position_sigma_m'] * 1e3:.3f} mm; pose whitened RMS {rep['residuals']['pose_whitened_rms']:.2f}"
          f"; gravity {np.array2string(np.array(rep['gravity_world_mps2']), precision=4)}")
    if hard:
        from scipy.spatial.transform import Rotation

        off_err = abs(rep["pose_time_offset_s"] - sim.truth.clock_offset_s)
        T = sim.truth.T_imu_frame
        q = rep["T_imu_pose"]["quat_wxyz"]
        ang = np.degrees((Rotation.from_quat([q[1], q[2], q[3], q[0]]).inv() * Rotation.from_matrix(T[:3, :3])).magnitude())
        terr = np.linalg.norm(np.array(rep["T_imu_pose"]["p_m"]) - T[:3, 3])
        print(f"[{name}] offset error {off_err * 1e3:.3f} ms (std {rep['pose_time_offset_std_s'] * 1e3:.3f} ms; "
              f"target < 1 ms: {_mark(off_err < 1e-3)})")
        print(f"[{name}] extrinsic error {ang:.3f} deg, {terr * 100:.2f} cm (targets 0.5 deg / 1 cm: "
              f"{_mark(ang < 0.5 and terr < 0.01)})")
        print(f"[{name}] outliers rejected {rep['outliers_rejected']} (20 injected)")
        if clean_rmse is not None:
            ratio_g, ratio_a = (rg / clean_rmse[0]).max(), (ra / clean_rmse[1]).max()
            print(f"[{name}] RMSE ratio to clean: gyro {ratio_g:.2f}, acc {ratio_a:.2f} (target <= 1.5: "
                  f"{_mark(ratio_g <= 1.5 and ratio_a <= 1.5)})")
    if rep["warnings"]:
        print(f"[{name}] warnings: {rep['warnings']}")
    return rg, ra


def case_v101():
    import pandas as pd

    from pipeline.io import load_sequence
    from pipeline.io.tum import read_tum_poses
    from pipeline.types import PoseSourceKind
    from recovery.recover import recover

    seq = load_sequence(DATA / "euroc/V1_01_easy")
    poses, _ = read_tum_poses(DATA / "euroc/V1_01_easy/ov_data/V1_01_easy_original.txt",
                              source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
    seq.poses = {"euroc_gt": poses}
    t0 = time.perf_counter()
    res = recover(seq, pose_stream="euroc_gt", config=_config())
    dt = time.perf_counter() - t0
    ref = pd.read_csv(DATA / "euroc/V1_01_easy_proto_excerpt/mav0/state_groundtruth_estimate0/data.csv").to_numpy()
    t_ref = ref[:, 0].astype(np.int64)
    sel = (res.t_ns >= t_ref[0]) & (res.t_ns <= t_ref[-1])
    ours = np.hstack([res.bias_gyro_radps, res.bias_acc_mps2])[sel]
    theirs = np.stack([np.interp(res.t_ns[sel], t_ref, ref[:, c]) for c in range(11, 17)], 1)
    d = ours - theirs
    mean_d, max_d = np.abs(d.mean(0)), np.abs(d).max(0)
    ok_mean = (mean_d[:3] <= 2e-3).all() and (mean_d[3:] <= 0.08).all()
    ok_max = (max_d[:3] <= 2e-3).all() and (max_d[3:] <= 0.08).all()
    print(f"[v101] {res.report['keyframes']} keyframes over {res.report['duration_s']:.1f} s, runtime {dt:.1f} s")
    print(f"[v101] first 5 s: |mean difference| gyro {np.array2string(mean_d[:3], precision=5)} acc "
          f"{np.array2string(mean_d[3:], precision=4)} ({_mark(ok_mean)}); max |difference| gyro "
          f"{np.array2string(max_d[:3], precision=5)} acc {np.array2string(max_d[3:], precision=4)} ({_mark(ok_max)})")
    n = res.report["noise"]
    print(f"[v101] noise chosen: gyro rw x{n['gyro_random_walk_scale']:.3g}, acc rw x{n['acc_random_walk_scale']:.3g}, "
          f"pose sigma {n['position_sigma_m'] * 1e3:.3f} mm; warnings {res.report['warnings']}")


def case_mh01():
    from pipeline.io import load_sequence
    from pipeline.io.tum import read_tum_poses
    from pipeline.types import PoseSourceKind
    from recovery.recover import agreement_z, recover

    seq = load_sequence(DATA / "euroc/MH_01_easy")
    t0 = time.perf_counter()
    ra = recover(seq, pose_stream="leica0", config=_config())
    t1 = time.perf_counter()
    gt, _ = read_tum_poses(DATA / "euroc/MH_01_easy/ov_data/MH_01_easy.txt",
                           source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
    seq.poses["euroc_gt"] = gt
    rb = recover(seq, pose_stream="euroc_gt", config=_config())
    t2 = time.perf_counter()
    z = agreement_z(ra, rb)
    frac_axes = (z < 3).mean(0)
    frac_all = float((z < 3).all(1).mean())
    rep = ra.report
    print(f"[mh01] leica: {rep['keyframes']} keyframes, offset {rep['pose_time_offset_s'] * 1e3:+.2f} ms "
          f"+- {rep['pose_time_offset_std_s'] * 1e3:.2f}, lever arm {np.round(rep['T_imu_pose']['p_m'], 4).tolist()}, "
          f"runtime {t1 - t0:.1f} s; gt: {rb.report['keyframes']} keyframes, runtime {t2 - t1:.1f} s")
    print(f"[mh01] within combined 3 sigma: per axis {np.array2string(frac_axes, precision=3)}, all axes "
          f"{frac_all:.3f} (target >= 0.95 per axis: {_mark(bool((frac_axes >= 0.95).all()))})")
    print(f"[mh01] leica warnings {rep['warnings']}; gt warnings {rb.report['warnings']}")


def _peak_rss_mb() -> float:
    """Peak RSS of this process. VmHWM (reset by exec) rather than ru_maxrss, which on Linux
    keeps the forking parent's peak across fork+exec and would report the benchmark parent."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


SPEED_SETTINGS = {
    "default": {},  # every pose sample, fused into 10-Hz keyframes
    "every-sample-keyframes": {"pose_fusion": False},  # each 100-Hz sample its own keyframe (slow)
    "20hz-no-fusion": {"pose_fusion": False, "keyframe_rate_hz": 20.0},  # samples between keyframes dropped
}


def _speed_child(store: str, setting: str, out: str) -> None:
    t0 = time.perf_counter()
    c0 = time.process_time()
    from pipeline.io import load_sequence
    from recovery.recover import write_recovery
    from recovery.recover import recover

    seq = load_sequence(store)
    cfg = _config(**SPEED_SETTINGS[setting])
    res = recover(seq, config=cfg)
    write_recovery(res, out)
    dt = time.perf_counter() - t0
    cpu = time.process_time() - c0
    rss_mb = _peak_rss_mb()
    print(json.dumps({"seconds": dt, "cpu_seconds": cpu, "peak_rss_mb": rss_mb, "duration_s": res.report["duration_s"],
                      "keyframes": res.report["keyframes"], "timings": res.report["timings_s"]}))


def case_speed(long: bool):
    from pipeline.store import write_store

    cases = [(180.0, "default"), (180.0, "20hz-no-fusion"), (180.0, "every-sample-keyframes")]
    if long:
        cases += [(3600.0, "default"), (3600.0, "20hz-no-fusion")]
    with tempfile.TemporaryDirectory() as tmp:
        for dur, kr in cases:
            store = Path(tmp) / f"sim_{int(dur)}"
            if not store.exists():
                write_store(_sim(dur, extrinsic_known=True).sequence, store)
            env = dict(os.environ, OMP_NUM_THREADS="2", PYTHONPATH=str(REPO))
            proc = subprocess.run([sys.executable, __file__, "--speed-child", str(store), kr, str(Path(tmp) / "out")],
                                  capture_output=True, text=True, env=env)
            if proc.returncode != 0:
                print(f"[speed] {dur:.0f} s, keyframes {kr}: FAILED: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            label = kr
            ok = dur != 180.0 or kr != "default" or (r["seconds"] <= 3 and r["peak_rss_mb"] <= 300)
            print(f"[speed] {dur:.0f} s IMU, {label}: {r['seconds']:.1f} s read->written "
                  f"({r.get('cpu_seconds', float('nan')):.1f} s CPU), peak RSS "
                  f"{r['peak_rss_mb']:.0f} MB, {dur / r['seconds']:.1f}x real time, {r['keyframes']} keyframes"
                  + (f" (target <= 3 s, <= 300 MB: {_mark(ok)})" if dur == 180.0 and kr == "default" else "")
                  + f"; stages {json.dumps({k: round(v, 1) for k, v in r['timings'].items()})}")
    print(f"[speed] load average at the end: {os.getloadavg()} on {os.cpu_count()} cores (shared machine)")


# ----------------------------------------------------------------------------- speed peer

PEER_KEYFRAME_RATE_HZ = 10.0  # the default recover's keyframe rate (fused 10-Hz keyframes)


def _peer_keyframes(pose_t_ns: np.ndarray, imu_t_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the peer's keyframes: the first pose sample of each 1/rate bin inside the IMU span."""
    inside = np.nonzero((pose_t_ns > imu_t_ns[0]) & (pose_t_ns < imu_t_ns[-1]))[0]
    bins = np.floor((pose_t_ns[inside] - imu_t_ns[0]) * rate_hz / 1e9).astype(np.int64)
    return inside[np.unique(bins, return_index=True)[1]]


def _peer_steps(imu_t_ns: np.ndarray, kf_t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU steps split at the keyframes: (IMU sample index held over the step, dt_s, keyframe interval)."""
    grid = np.union1d(imu_t_ns[(imu_t_ns > kf_t_ns[0]) & (imu_t_ns < kf_t_ns[-1])], kf_t_ns)
    sample = np.searchsorted(imu_t_ns, grid[:-1], side="right") - 1  # zero-order hold, GTSAM's convention
    interval = np.searchsorted(kf_t_ns, grid[:-1], side="right") - 1
    return sample, np.diff(grid) / 1e9, interval


def plain_gtsam_batch(sequence, stream: str, given: dict, marginals: bool = True) -> dict:
    """The speed peer: one plain GTSAM batch, everything given, nothing estimated.

    What a GTSAM user would write for bias ground truth when the extrinsic ``T_imu_pose``, the
    clock offset, the IMU noise, the pose noise and gravity are known: one pose sample per
    keyframe (the default recover's 10 Hz, the samples between them unused), one
    ``PreintegratedCombinedMeasurements`` per keyframe interval fed the raw samples (GTSAM's
    zero-order hold, split at the keyframes), ``CombinedImuFactor`` + ``PriorFactorPose3``, a weak
    prior on the first bias, ``LevenbergMarquardtOptimizer`` with default parameters, then (with
    ``marginals``) ``gtsam.Marginals`` queried at every keyframe's bias for its 1-sigma: the same
    product as ``recover`` (bias and std per keyframe). No offset, extrinsic, noise or gravity
    estimation, no pose fusion, no outlier rejection, no segments.

    Returns:
        ``t_ns`` [K], ``bias`` [K, 6] (gyro, acc), ``bias_std`` [K, 6] (NaN without marginals),
        ``solve_s`` / ``marginals_s`` (seconds).
    """
    import gtsam
    from gtsam.symbol_shorthand import B, V, X

    t0 = time.perf_counter()
    imu, poses = sequence.imu, sequence.poses[stream]
    t_pose = poses.t_ns + int(round(given["offset_s"] * 1e9))
    kf = _peer_keyframes(t_pose, imu.t_ns, PEER_KEYFRAME_RATE_HZ)
    kf_t = t_pose[kf]
    params = gtsam.PreintegrationCombinedParams(np.asarray(given["gravity_mps2"], dtype=float))
    for setter, key in ((params.setGyroscopeCovariance, "gyro_noise_density"),
                        (params.setAccelerometerCovariance, "acc_noise_density"),
                        (params.setBiasOmegaCovariance, "gyro_random_walk"),
                        (params.setBiasAccCovariance, "acc_random_walk")):
        setter(given[key] ** 2 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))
    E = gtsam.Pose3(np.asarray(given["T_imu_pose"], dtype=float))
    Ad = E.AdjointMap()
    pose_cov = Ad @ np.diag([given["rotation_sigma_rad"] ** 2] * 3 + [given["position_sigma_m"] ** 2] * 3) @ Ad.T
    pose_model = gtsam.noiseModel.Gaussian.Covariance(0.5 * (pose_cov + pose_cov.T))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    Xs = [gtsam.Pose3(gtsam.Rot3.Quaternion(*poses.quat_wxyz[i]), poses.p_m[i]).compose(E.inverse()) for i in kf]
    vel = np.gradient(np.array([x.translation() for x in Xs]), kf_t / 1e9, axis=0)
    zero = gtsam.imuBias.ConstantBias()
    for k, x in enumerate(Xs):
        graph.add(gtsam.PriorFactorPose3(X(k), x, pose_model))
        values.insert(X(k), x)
        values.insert(V(k), vel[k])
        values.insert(B(k), zero)
    graph.add(gtsam.PriorFactorConstantBias(B(0), zero, gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    sample, dt_s, interval = _peer_steps(imu.t_ns, kf_t)
    bounds = np.searchsorted(interval, np.arange(len(kf) + 1))
    for k in range(len(kf) - 1):
        pim = gtsam.PreintegratedCombinedMeasurements(params, zero)
        for j in range(bounds[k], bounds[k + 1]):
            pim.integrateMeasurement(imu.acc_mps2[sample[j]], imu.gyro_radps[sample[j]], dt_s[j])
        graph.add(gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pim))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    bias = np.array([np.r_[result.atConstantBias(B(k)).gyroscope(), result.atConstantBias(B(k)).accelerometer()]
                     for k in range(len(kf))])
    t1 = time.perf_counter()
    std = np.full_like(bias, np.nan)
    if marginals:
        marg = gtsam.Marginals(graph, result)
        for k in range(len(kf)):
            c = np.sqrt(np.diag(marg.marginalCovariance(B(k))))
            std[k] = np.r_[c[3:], c[:3]]
    return {"t_ns": kf_t, "bias": bias, "bias_std": std, "solve_s": t1 - t0, "marginals_s": time.perf_counter() - t1}


def _peer_child(store: str, given_path: str, out: str) -> None:
    """In one process: the default ``recover`` and the plain GTSAM peer on one loaded sequence, each
    timed ``PEER_REPEATS`` times in back-to-back pairs (the machine is shared)."""
    from pipeline.io import load_sequence
    from recovery.recover import recover

    seq = load_sequence(store)
    given = json.loads(Path(given_path).read_text())
    cfg = _config()
    runs: dict[str, list[float]] = {"recover": [], "peer": [], "peer_solve": [], "recover_cpu": [], "peer_cpu": []}

    def run_recover():
        t0, c0 = time.perf_counter(), time.process_time()
        out = recover(seq, config=cfg)
        runs["recover"].append(time.perf_counter() - t0)
        runs["recover_cpu"].append(time.process_time() - c0)
        return out

    def run_peer() -> dict:
        c0 = time.process_time()
        out = plain_gtsam_batch(seq, given["stream"], given)
        runs["peer_cpu"].append(time.process_time() - c0)
        runs["peer"].append(out["solve_s"] + out["marginals_s"])
        runs["peer_solve"].append(out["solve_s"])
        return out

    for i in range(PEER_REPEATS):  # back-to-back pairs, in alternating order (the machine's speed drifts)
        if i % 2 == 0:
            res, peer = run_recover(), run_peer()
        else:
            peer, res = run_peer(), run_recover()
    np.savez(out, rec_t_ns=res.t_ns, rec_bias=np.hstack([res.bias_gyro_radps, res.bias_acc_mps2]),
             rec_std=np.hstack([res.bias_gyro_std_radps, res.bias_acc_std_mps2]), peer_t_ns=peer["t_ns"],
             peer_bias=peer["bias"], peer_std=peer["bias_std"])
    print(json.dumps({**{k: min(v) for k, v in runs.items()}, "all": runs, "keyframes": res.report["keyframes"],
                      "peer_keyframes": len(peer["t_ns"]), "timings": res.report["timings_s"]}))


def _peer_process_child(store: str, given_path: str, out: str) -> None:
    """The peer as a user runs it: start, imports, read, :func:`plain_gtsam_batch`, write (a CSV)."""
    from pipeline.io import load_sequence

    seq = load_sequence(store)
    given = json.loads(Path(given_path).read_text())
    res = plain_gtsam_batch(seq, given["stream"], given)
    np.savetxt(out, np.column_stack([res["t_ns"], res["bias"], res["bias_std"]]), delimiter=",")


def _child_cpu_s(args: list[str], env: dict) -> float:
    """CPU seconds (user + system) of one child process, from its start to its exit."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1:])
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _whole_process_pairs(store: Path, given: Path, tmp: Path, env: dict) -> tuple[list[float], list[float]]:
    """CPU seconds of ``PEER_REPEATS`` back-to-back pairs of whole processes (alternating order): the
    default recover read -> written (``--speed-child``) and the peer (``--peer-process``)."""
    rec, peer = [], []
    for i in range(PEER_REPEATS):
        pair = [(rec, ["--speed-child", str(store), "default", str(tmp / f"rec{i}")]),
                (peer, ["--peer-process", str(store), str(given), str(tmp / f"peer{i}.csv")])]
        for times, args in (pair if i % 2 == 0 else pair[::-1]):
            times.append(_child_cpu_s(args, env))
    return rec, peer


PEER_REPEATS = 9
#: Goal: the default recover's CPU at most this many times the plain batch's.
PEER_GOAL = 1.5
PEER_DURATION_S = 180.0


def _rmse_nees(t_ns, bias, std, sim) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis RMSE [6] and NEES [6] of a bias track against the simulator's truth."""
    truth = np.hstack([sim.truth.bias_gyro_radps, sim.truth.bias_acc_mps2])
    ref = np.stack([np.interp(t_ns, sim.truth.t_ns, truth[:, c]) for c in range(6)], 1)
    err = bias - ref
    return np.sqrt((err**2).mean(0)), ((err / std) ** 2).mean(0)


def case_peer():
    """Speed of the default ``recover`` (everything estimated, marginals on) against
    :func:`plain_gtsam_batch` (everything given), both in one child process on the same sequence."""
    from pipeline.store import write_store

    sim = _sim(PEER_DURATION_S, extrinsic_known=True)
    imu_cfg, pose_cfg = sim.config.imu, sim.config.poses
    given = {"stream": next(iter(sim.sequence.poses)), "offset_s": sim.truth.clock_offset_s,
             "T_imu_pose": sim.truth.T_imu_frame.tolist(), "gravity_mps2": np.asarray(sim.truth.gravity_mps2).tolist(),
             "position_sigma_m": pose_cfg.position_noise_m, "rotation_sigma_rad": pose_cfg.rotation_noise_rad,
             **{k: getattr(imu_cfg, k) for k in ("gyro_noise_density", "acc_noise_density", "gyro_random_walk",
                                                 "acc_random_walk")}}
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "sim"
        write_store(sim.sequence, store)
        (Path(tmp) / "given.json").write_text(json.dumps(given))
        out = Path(tmp) / "tracks.npz"
        env = dict(os.environ, OMP_NUM_THREADS="2", PYTHONPATH=str(REPO))
        proc = subprocess.run([sys.executable, __file__, "--peer-child", str(store), str(Path(tmp) / "given.json"),
                               str(out)], capture_output=True, text=True, env=env)
        if proc.returncode != 0:
            print(f"[peer] FAILED: {proc.stderr.strip().splitlines()[-1:]}")
            return
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        tracks = dict(np.load(out))
        whole_rec, whole_peer = _whole_process_pairs(store, Path(tmp) / "given.json", Path(tmp), env)
    rec = _rmse_nees(tracks["rec_t_ns"], tracks["rec_bias"], tracks["rec_std"], sim)
    peer = _rmse_nees(tracks["peer_t_ns"], tracks["peer_bias"], tracks["peer_std"], sim)
    paired = float(np.median(np.divide(r["all"]["recover_cpu"], r["all"]["peer_cpu"])))
    wall, cpu = r["recover"] / r["peer"], r["recover_cpu"] / r["peer_cpu"]
    print(f"[peer] {PEER_DURATION_S:.0f} s of 200-Hz IMU + 100-Hz mocap, one process, best of {PEER_REPEATS}: default "
          f"recover {r['recover']:.2f} s ({r['keyframes']} keyframes; offset, noise, gravity estimated, marginals on; "
          f"stages {json.dumps({k: round(v, 2) for k, v in r['timings'].items()})})")
    print(f"[peer] plain GTSAM batch (calibration, noise, offset given; {r['peer_keyframes']} keyframes): "
          f"{r['peer']:.2f} s with its bias marginals ({r['peer_solve']:.2f} s solve only)")
    print(f"[peer] ratio default / peer, CPU seconds, median of the {PEER_REPEATS} back-to-back pairs "
          f"{paired:.2f} (goal <= {PEER_GOAL}: {_mark(paired <= PEER_GOAL)}); best / best: wall clock {wall:.2f} "
          f"({_mark(wall <= PEER_GOAL)}), CPU {r['recover_cpu']:.2f} / {r['peer_cpu']:.2f} = {cpu:.2f} ({_mark(cpu <= PEER_GOAL)}); "
          f"against the peer's solve alone {r['recover'] / r['peer_solve']:.2f}. The machine's speed drifts "
          "between runs by up to 1.5x: the pairs' median follows it, a best of each can pair a fast stretch "
          f"with a slow one; all runs {json.dumps({k: [round(x, 2) for x in v] for k, v in r['all'].items()})}")
    whole = float(np.median(np.divide(whole_rec, whole_peer)))
    print(f"[peer] whole processes as a user runs them (start, imports, read, solve, write), CPU seconds, "
          f"best of {PEER_REPEATS}: recover {min(whole_rec):.2f}, peer {min(whole_peer):.2f}; ratio, median of the "
          f"pairs {whole:.2f} (goal <= {PEER_GOAL}: {_mark(whole <= PEER_GOAL)}); all runs recover "
          f"{[round(x, 2) for x in whole_rec]}, peer {[round(x, 2) for x in whole_peer]}")
    for name, (rmse, nees) in (("recover", rec), ("peer", peer)):
        print(f"[peer] {name:7s} RMSE gyro {np.array2string(rmse[:3], precision=6)} rad/s, acc "
              f"{np.array2string(rmse[3:], precision=5)} m/s^2; NEES per axis {np.array2string(nees, precision=2)}")


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--speed-child":
        _speed_child(*sys.argv[2:5])
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "--peer-child":
        _peer_child(*sys.argv[2:5])
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "--peer-process":
        _peer_process_child(*sys.argv[2:5])
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=None, help="subset of: clean hard v101 mh01 speed peer")
    ap.add_argument("--long", action="store_true", help="include the 1-hour speed run")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2], help="simulation seeds of the hard case")
    ap.add_argument("--config", default=None,
                    help='RecoveryConfig overrides as a JSON object, e.g. \'{"segment_s": 30, "segment_overlap_s": 5}\'')
    args = ap.parse_args()
    if args.config:
        json.loads(args.config)  # fail early on bad JSON
        os.environ["BIASGT_BENCH_CONFIG"] = args.config  # the speed children inherit it
    import logging

    logging.basicConfig(level=logging.WARNING)
    todo = args.only or ["clean", "hard", "v101", "mh01", "speed", "peer"]
    clean = None
    if "clean" in todo:
        clean = case_sim(False)
    if "hard" in todo:
        for seed in args.seeds:
            case_sim(True, clean if seed == 0 else None, seed)  # the clean case is seed 0
    if "v101" in todo:
        case_v101()
    if "mh01" in todo:
        case_mh01()
    if "speed" in todo:
        case_speed(args.long)
    if "peer" in todo:
        case_peer()
    return 0


if __name__ == "__main__":
    sys.exit(main())
