"""Bias ground truth from EuRoC's raw motion capture, judged against EuRoC's own estimate (prints every figure).

Usage::

    .venv/bin/python benchmarks/recovery/euroc_real.py [--data DIR] [--only V1_02_medium MH_05_difficult ...]

For each sequence the real IMU is recovered with default options from its raw stream (``vicon0``:
6-DoF Vicon body, 100 Hz, stamps not on the IMU clock; ``leica0``: prism positions, ~20 Hz), each
recovery in a child process (runtime, peak RSS). Then, with non-overlapping 1-s windows:

* **against the ground truth**: EuRoC's ground-truth state where it exists (its nominal gravity),
  else its ground-truth poses (``ov_data``, IMU frame and clock): the recovered bias beside EuRoC's
  bias, a constant (the recovered bias's first window) and zero; on V1_01, whose EuRoC bias covers
  only the first 5 s, beside OpenVINS's re-estimate instead;
* **held out**: the recovery cross-validated by 10-s blocks (3 folds), against the raw stream where
  it has orientations (Vicon: the held-out blocks judge the verdict), else against the ground truth;
  EuRoC's bias, the constant and zero on the same held-out windows;
* **clock offset** beside an independent estimate from the ground truth (which is on the IMU clock):
  the lag that best correlates 0.1-s rotation angles (Vicon) or best fits the prism track (Leica) of the
  two streams; and beside a rotation-free one that needs no ground truth: the lag that best correlates
  the specific-force magnitude of the positions with the accelerometer's;
* **extrinsic**: the estimate's difference from ``sensor.yaml``'s T_BS with its sigma; noise scales,
  the correlated pose-error model and the outliers.
* **the position-only offset search checked**: on EuRoC's ground-truth positions alone (Leica sequences;
  on the IMU clock by construction, so an unbiased search reads 0) and on the Vicon positions alone (it
  should read what the 6-DoF search reads), both at 20 Hz;
* **which reference favours which bias** (sequences with EuRoC's state): both biases judged against the
  recovered trajectory instead of EuRoC's, and how far each trajectory's 1-s position second differences
  lie from the raw stream's (Vicon); and the gravity each bias fits best against EuRoC's state (is the
  state's frame level for the bias it was estimated with?), with the PRMSE there and at nominal gravity,
  beside the bias of the Vicon positions alone (20 Hz; attitude from the IMU, not from the stream's
  orientations or the extrinsic); and the constant IMU-frame rotation from EuRoC's state attitude to
  each recovered trajectory's (its tilt and heading parts), with every bias judged against EuRoC's
  positions and velocities under the state's attitude turned by it; and where the recovery, a closed-form
  fit of the Vicon and gyro rates, EuRoC's state attitude, sensor.yaml and (V1 room) rpng/vicon2gt's
  published estimate put the IMU on the Vicon body.

Goals (``ok`` columns): against the ground-truth state PRMSE <= 1.1x and ROE <= 1.5x EuRoC's bias and a
verdict other than FAIL; held out against the raw stream PRMSE and ROE <= 1.1x EuRoC's; where only
ground-truth poses exist, not FAIL and held out better than the constant and zero; the clock offset
within 5 ms of the independent estimate.
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing as mp
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation, Slerp

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from pipeline.bias_table import BiasTrack  # noqa: E402
from pipeline.configs import assignments_to_mapping  # noqa: E402
from pipeline.errors import ConfigError  # noqa: E402
from pipeline.io import load_sequence  # noqa: E402
from pipeline.io.tum import read_tum_poses  # noqa: E402
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind, Sequence, StateSeries  # noqa: E402
from recovery.result import RecoveryResult  # noqa: E402

DATA = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data"))
VICON = ("V1_01_easy", "V1_02_medium", "V1_03_difficult", "V2_01_easy", "V2_02_medium", "V2_03_difficult")
LEICA = ("MH_01_easy", "MH_03_medium", "MH_05_difficult")
GT_POSES = "groundtruth_poses"
WINDOW_OVERLAP = 0.0
LAG_GRID_S = np.arange(-0.5, 0.5 + 1e-9, 0.0005)
SPECIFIC_FORCE_FILTERS_S = (0.35, 0.55, 0.85)  # the middle one is the estimate, the others its spread


def stream_of(name: str) -> str:
    return "vicon0" if name in VICON else "leica0"


def load(data: Path, name: str) -> Sequence:
    """The sequence with, where EuRoC has no full state, its ground-truth poses as ``groundtruth_poses``."""
    seq = load_sequence(data / "euroc" / name)
    if seq.ground_truth is None:
        gt, _ = read_tum_poses(data / "euroc" / name / "ov_data" / f"{name}_original.txt"
                               if name == "V1_01_easy" else data / "euroc" / name / "ov_data" / f"{name}.txt",
                               source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
        seq.poses[GT_POSES] = gt
    return seq


def prism_lever_m(data: Path, name: str) -> np.ndarray:
    """The Leica prism's position in the IMU (body) frame: ``leica0/sensor.yaml``'s T_BS translation."""
    doc = yaml.safe_load((data / "euroc" / name / "mav0" / "leica0" / "sensor.yaml").read_text())
    return np.asarray(doc["T_BS"]["data"], dtype=float).reshape(4, 4)[:3, 3]


def gt_poses(seq: Sequence) -> PoseSeries:
    return seq.poses[GT_POSES] if GT_POSES in seq.poses else seq.ground_truth.to_pose_series()


# ----------------------------------------------------------------------------- independent offsets


def _best_lag(a: np.ndarray, b_of_lag, lags: np.ndarray) -> tuple[float, float]:
    """The lag maximising the Pearson correlation of ``a`` with ``b_of_lag(lag)`` (parabolic refinement)."""
    corr = []
    for lag in lags:
        b = b_of_lag(lag)
        ok = np.isfinite(a) & np.isfinite(b)
        corr.append(np.corrcoef(a[ok], b[ok])[0, 1] if ok.sum() > 100 else -1.0)
    corr = np.array(corr)
    k = int(np.argmax(corr))
    step = lags[1] - lags[0]
    if 0 < k < len(corr) - 1:
        den = corr[k - 1] - 2 * corr[k] + corr[k + 1]
        return float(lags[k] + (0.5 * (corr[k - 1] - corr[k + 1]) / den * step if den else 0.0)), float(corr[k])
    return float(lags[k]), float(corr[k])


def independent_offset_rotation(stream: PoseSeries, reference: PoseSeries, h_s: float = 0.1) -> tuple[float, float]:
    """Seconds to add to ``stream``'s stamps to put it on ``reference``'s clock: the lag that best
    correlates the rotation angles over ``h_s`` of the two (angles: no extrinsic needed)."""
    t0 = int(reference.t_ns[0])
    tr, ts = (reference.t_ns - t0) / NS_PER_S, (stream.t_ns - t0) / NS_PER_S
    sr = Slerp(tr, Rotation.from_quat(reference.quat_wxyz, scalar_first=True))
    ss = Slerp(ts, Rotation.from_quat(stream.quat_wxyz, scalar_first=True))
    grid = np.arange(max(tr[0], ts[0]) + 1.0, min(tr[-1], ts[-1]) - 1.0 - h_s, 0.005)
    a = (sr(grid).inv() * sr(grid + h_s)).magnitude()

    def b(lag: float) -> np.ndarray:
        g = grid - lag
        ok = (g >= ts[0]) & (g + h_s <= ts[-1])
        out = np.full(len(grid), np.nan)
        out[ok] = (ss(g[ok]).inv() * ss(g[ok] + h_s)).magnitude()
        return out

    return _best_lag(a, b, LAG_GRID_S)


def independent_offset_position(stream: PoseSeries, reference: PoseSeries, p_imu_prism_m: np.ndarray,
                                max_gap_s: float = 0.2) -> tuple[float, float]:
    """As :func:`independent_offset_rotation` for a position-only stream: the lag minimising the RMS
    distance between the prism's positions and the reference's prism track (IMU pose moved by the
    calibration's lever ``p_imu_prism_m``), after the best rigid alignment of the two world frames
    (``scipy.spatial.transform.Rotation.align_vectors`` on centred tracks). Returns ``(lag, rms_m)``;
    only prism samples with reference samples within ``max_gap_s`` on both sides count."""
    t0 = int(reference.t_ns[0])
    tr, ts = (reference.t_ns - t0) / NS_PER_S, (stream.t_ns - t0) / NS_PER_S
    sr = Slerp(tr, Rotation.from_quat(reference.quat_wxyz, scalar_first=True))

    def cost(lag: float) -> float:
        t = ts + lag  # the prism samples on the reference clock
        j = np.searchsorted(tr, t)
        ok = (j > 0) & (j < len(tr))
        ok[ok] &= (tr[j[ok]] - tr[j[ok] - 1]) <= max_gap_s
        t, target = t[ok], stream.p_m[ok]
        p_imu = np.stack([np.interp(t, tr, reference.p_m[:, c]) for c in range(3)], 1)
        prism = p_imu + sr(t).apply(p_imu_prism_m)
        a, b = prism - prism.mean(0), target - target.mean(0)
        rot, _ = Rotation.align_vectors(a, b)
        return float(np.sqrt(np.mean(np.sum((rot.apply(b) - a) ** 2, axis=1))))

    coarse = LAG_GRID_S[::10]
    c = np.array([cost(lag) for lag in coarse])
    k = int(np.argmin(c))
    fine = LAG_GRID_S[(LAG_GRID_S >= coarse[max(k - 1, 0)]) & (LAG_GRID_S <= coarse[min(k + 1, len(coarse) - 1)])]
    f = np.array([cost(lag) for lag in fine])
    m = int(np.argmin(f))
    if 0 < m < len(fine) - 1:  # parabolic refinement
        den = f[m - 1] - 2 * f[m] + f[m + 1]
        shift = 0.5 * (f[m - 1] - f[m + 1]) / den if den > 0 else 0.0
        return float(fine[m] + shift * (fine[1] - fine[0])), float(f[m])
    return float(fine[m]), float(f[m])


def specific_force_offset(imu: ImuSeries, positions: PoseSeries, filter_s: float, rate_hz: float = 20.0,
                          gravity_mps2: float = 9.81) -> tuple[float, float]:
    """Seconds to add to ``positions``' stamps to put them on the IMU clock, from no ground truth: the lag
    that best correlates the specific-force magnitude ``|p'' - g|`` of the positions (resampled at
    ``rate_hz``, Savitzky-Golay second derivative over ``filter_s``) with the accelerometer's ``|f|``
    (0.05-s box mean against vibration, then the same Savitzky-Golay smoothing). A magnitude needs
    neither the attitude nor the world frame's heading; a level world frame (z up) is assumed."""
    t0 = int(positions.t_ns[0])
    tp, ti = (positions.t_ns - t0) / NS_PER_S, (imu.t_ns - t0) / NS_PER_S
    grid = np.arange(tp[0], tp[-1], 1.0 / rate_hz)
    n = int(round(filter_s * rate_hz)) | 1
    p = np.stack([np.interp(grid, tp, positions.p_m[:, c]) for c in range(3)], 1)
    a = savgol_filter(p, n, 3, deriv=2, delta=1.0 / rate_hz, axis=0)
    a[:, 2] += gravity_mps2
    pose_f = np.linalg.norm(a, axis=1)
    gap = np.interp(grid, tp[1:], np.diff(tp)) > 3.0 / rate_hz  # interpolated across a dropout
    pose_f[gap | (np.arange(len(grid)) < n) | (np.arange(len(grid)) >= len(grid) - n)] = np.nan
    k = max(1, int(round(0.05 / np.median(np.diff(ti))))) | 1  # odd: a centred mean
    box = np.stack([np.convolve(imu.acc_mps2[:, c], np.ones(k) / k, mode="same") for c in range(3)], 1)
    imu_f = np.linalg.norm(box, axis=1)

    def b(lag: float) -> np.ndarray:
        t = grid + lag
        out = savgol_filter(np.interp(t, ti, imu_f), n, 3, axis=0)
        out[(t < ti[0]) | (t > ti[-1])] = np.nan
        return out

    return _best_lag(pose_f, b, LAG_GRID_S)


def recovery_of_positions(seq: Sequence, poses: PoseSeries, rate_hz: float = 20.0) -> RecoveryResult:
    """The recovery, with default options, of ``poses``' positions alone, taken at ``rate_hz`` as a
    position-only stream: its attitude comes from the IMU and the positions, never from the stream's.

    Its clock offset checks the position-only search that the Leica sequences rely on: on EuRoC's
    ground-truth positions (on the IMU clock by construction) an unbiased search reads 0; on the Vicon
    positions it should read what the 6-DoF search reads. Its bias, on the Vicon positions, is a second
    answer from the raw stream that does not go through the stream's orientations or the extrinsic."""
    import dataclasses

    from recovery.config import RecoveryConfig
    from recovery.recover import recover

    step = max(1, int(round(poses.rate_hz / rate_hz)))
    positions = dataclasses.replace(poses.take(np.arange(0, len(poses.t_ns), step)), quat_wxyz=None,
                                    source_kind=PoseSourceKind.POSITION_TRACKER, frame="positions_alone")
    alone = dataclasses.replace(seq, poses={"positions_alone": positions}, ground_truth=None)
    return recover(alone, pose_stream="positions_alone", config=RecoveryConfig())


def _offset(result: RecoveryResult) -> tuple[float, float]:
    return float(result.report["pose_time_offset_s"]), float(result.report["pose_time_offset_std_s"])


# ----------------------------------------------------------------------------- which reference favours which bias


def _second_differences_m(t_s: np.ndarray, p_m: np.ndarray, t0: np.ndarray, tm: np.ndarray, t1: np.ndarray,
                          h_s: float = 0.5) -> np.ndarray:
    """Second differences of the positions over ``t0 < tm < t1`` (about ``h_s`` apart), as the
    equivalent ``p(t + 2h) - 2 p(t + h) + p(t)`` of a uniform step ``h_s``, [G, 3] (m): the mean
    acceleration they imply times ``h_s^2``. Positions interpolated linearly in ``t_s``."""
    def at(t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, t_s, p_m[:, c]) for c in range(3)], 1)

    hm, hp = (tm - t0)[:, None], (t1 - tm)[:, None]
    acc = 2 * (hm * at(t1) - (hm + hp) * at(tm) + hp * at(t0)) / (hm * hp * (hm + hp))
    return acc * h_s**2


def trajectory_agreement_mm(seq: Sequence, raw: PoseSeries, report: dict, ours: PoseSeries) -> dict[str, float]:
    """RMS difference [mm] of the IMU position's 1-s second differences (what a 1-s integration
    checks) between EuRoC's ground-truth state, the raw 6-DoF stream moved to the IMU with the
    recovery's offset and extrinsic, and the recovery's own trajectory. The differences are taken at
    the recovery's keyframe stamps (no interpolation of its 10-Hz keyframes; the 100-Hz and 200-Hz
    streams are interpolated linearly). The ground truth's world frame is rotated onto the raw
    stream's first (Kabsch on the differences)."""
    T = report["T_imu_pose"]
    R_ip = Rotation.from_quat(T["quat_wxyz"], scalar_first=True).as_matrix()
    R_wi = Rotation.from_quat(raw.quat_wxyz, scalar_first=True).as_matrix() @ R_ip.T
    p_raw = raw.p_m - np.einsum("nij,j->ni", R_wi, np.asarray(T["p_m"], dtype=float))
    gt = seq.ground_truth.to_pose_series()
    t_raw = raw.t_ns / NS_PER_S + report["pose_time_offset_s"]
    t_gt, t_ours = gt.t_ns / NS_PER_S, ours.t_ns / NS_PER_S
    step = max(1, int(round(0.5 / np.median(np.diff(t_ours)))))
    k = np.arange(0, len(t_ours) - 2 * step, step)
    t0, tm, t1 = t_ours[k], t_ours[k + step], t_ours[k + 2 * step]
    ok = ((t0 > max(t_raw[0], t_gt[0])) & (t1 < min(t_raw[-1], t_gt[-1]))
          & (np.abs(t1 - t0 - 2 * step * np.median(np.diff(t_ours))) < 0.05))  # no gap inside
    t0, tm, t1 = t0[ok], tm[ok], t1[ok]
    d_raw, d_gt, d_ours = (_second_differences_m(t, p, t0, tm, t1) for t, p in
                           ((t_raw, p_raw), (t_gt, gt.p_m), (t_ours, ours.p_m)))
    d_gt = Rotation.align_vectors(d_raw, d_gt)[0].apply(d_gt)

    def rms(x: np.ndarray) -> float:
        return float(1e3 * np.sqrt(np.mean(np.sum(x**2, axis=1))))

    return {"ground_truth_vs_raw": rms(d_gt - d_raw), "ours_vs_raw": rms(d_ours - d_raw),
            "ground_truth_vs_ours": rms(d_gt - d_ours)}


def _state_end_errors(seq: Sequence, tracks: dict[str, BiasTrack],
                      state: StateSeries | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per row of ``tracks``, the end-position errors [W, 3] (m) of the non-overlapping 1-s windows
    integrated from ``state`` (default: EuRoC's ground-truth state) with nominal gravity, and each
    window's ``T^2 / 2`` [W] (s^2); windows where a bias is clamped (outside its track) are left out."""
    from interpolation.bias import interpolate_bias
    from pipeline.geometry.integration import integrate_numpy
    from validation.config import ValidationConfig
    from validation.metrics import plan_windows
    from validation.reference import reference_from_states

    imu = seq.imu
    ref = reference_from_states(seq.ground_truth if state is None else state, imu.t_ns)
    plan = plan_windows(imu, ValidationConfig(overlap=WINDOW_OVERLAP))
    n, s = plan.n, plan.starts[plan.keep]
    s = s[ref.valid[s] & ref.valid[s + n]]
    idx = s[:, None] + np.arange(n + 1)[None, :]
    dt = np.diff(imu.t_ns[idx], axis=1) / NS_PER_S
    half_T2 = 0.5 * dt.sum(axis=1) ** 2
    out = {}
    for name, track in tracks.items():
        at = interpolate_bias(track, imu.t_ns, random_walk=np.zeros(6), clamp=True)
        ok = ~np.any(at.clamped[idx], axis=1)
        b = at.bias[idx[ok]]
        res = integrate_numpy(imu.gyro_radps[idx[ok]], imu.acc_mps2[idx[ok]], dt[ok], ref.R[s[ok]], ref.v[s[ok]],
                              ref.p[s[ok]], gravity_mps2=np.array([0.0, 0.0, -9.81]),
                              bias_gyro_radps=b[..., :3], bias_acc_mps2=b[..., 3:])
        out[name] = (ref.p[s[ok] + n] - res.p, half_T2[ok])
    return out


def _rms_norm(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def preferred_tilt(seq: Sequence, tracks: dict[str, BiasTrack]) -> dict[str, dict]:
    """The gravity each bias fits best against EuRoC's ground-truth state, by row (``tracks``).

    A window's end position is linear in gravity, ``p(g) = p(g0) + T^2 / 2 (g - g0)``, so one
    integration with nominal gravity ``g0`` gives, in closed form, the horizontal gravity components
    that minimise the row's PRMSE over the non-overlapping windows (z kept). Returns, per row, the
    tilt of that gravity from -z (deg), the gravity, and the PRMSE (m) there and at nominal.
    """
    out = {}
    for name, (e, w) in _state_end_errors(seq, tracks).items():  # e: what a gravity change must explain
        dg = np.zeros(3)
        dg[:2] = (w[:, None] * e[:, :2]).sum(0) / np.sum(w**2)
        g = np.array([0.0, 0.0, -9.81]) + dg
        out[name] = {"tilt_deg": float(np.degrees(np.arctan2(np.hypot(*g[:2]), -g[2]))), "gravity_mps2": g.tolist(),
                     "prmse_m": _rms_norm(e - w[:, None] * dg), "prmse_nominal_m": _rms_norm(e), "windows": len(w)}
    return out


def attitude_offsets(seq: Sequence, trajectories: dict[str, PoseSeries],
                     tracks: dict[str, BiasTrack]) -> dict[str, dict]:
    """How EuRoC's ground-truth attitude sits on the IMU, against each trajectory of ``trajectories``.

    Per trajectory, what ``validate`` records as ``reference_attitude``
    (:func:`validation.attitude.reference_attitude_offset`: the mean IMU-frame rotation ``dR`` from the
    state's attitude to the trajectory's, its tilt and heading parts and spread), and the PRMSE (m,
    nominal gravity) of every row of ``tracks`` against EuRoC's state with its attitude turned to
    ``R_state dR``: each bias judged on the attitude it would have been fitted to, from the same
    positions and velocities.
    """
    import dataclasses

    from validation.attitude import reference_attitude_offset
    from validation.reference import reference_from_states

    gt = seq.ground_truth
    ref = reference_from_states(gt, seq.imu.t_ns)
    R_state = Rotation.from_quat(gt.quat_wxyz, scalar_first=True)
    out = {}
    for name, traj in trajectories.items():
        off = reference_attitude_offset(ref, traj, np.array([0.0, 0.0, -9.81]))
        dR = Rotation.from_rotvec(np.radians(off.rotvec_deg))
        turned = dataclasses.replace(gt, quat_wxyz=(R_state * dR).as_quat(scalar_first=True))
        out[name] = {**off.to_dict(),
                     "prmse_m": {k: _rms_norm(e) for k, (e, _) in _state_end_errors(seq, tracks, turned).items()}}
    return out


#: rpng/vicon2gt's published R_BtoI for EuRoC's V1 room (``launch/eurocmav.launch``): the IMU's rotation
#: from the Vicon body, R_imu_pose.
VICON2GT_R_IMU_POSE_V1 = np.array([[0.337977, 0.000209931, 0.941155], [0.0261378, -0.999616, -0.00916333],
                                   [0.940792, 0.0276967, -0.337852]])


def mounting_angles_deg(seq: Sequence, raw: PoseSeries, report: dict) -> dict[str, float]:
    """Where four sources put the IMU on the Vicon body (R_imu_pose), as angles (deg) from the recovered one:

    * ``closed_form``: Kabsch on the Vicon and gyro rates, no graph
      (:func:`recovery.calibration_init.extrinsic.estimate_extrinsic_rotation`, at the recovered offset);
    * ``euroc_state``: the mean of ``R_state^T R_world_pose`` over the Vicon stamps (the mounting EuRoC's
      state attitude implies), and ``euroc_state_spread`` its per-stamp RMS spread about that mean;
    * ``sensor_yaml``: the calibration file's T_BS;
    * ``vicon2gt`` (V1 room only): rpng/vicon2gt's published estimate; with ``vicon2gt_vs_euroc_state``.
    """
    from recovery.calibration_init.extrinsic import estimate_extrinsic_rotation

    def angle(a: Rotation, b: Rotation) -> float:
        return float(np.degrees((a.inv() * b).magnitude()))

    offset_s = report["pose_time_offset_s"]
    rec = Rotation.from_quat(report["T_imu_pose"]["quat_wxyz"], scalar_first=True)
    closed = Rotation.from_matrix(estimate_extrinsic_rotation(seq.imu, raw, offset_s).R_imu_pose)
    gt = seq.ground_truth.to_pose_series()
    t_gt, t_raw = gt.t_ns / NS_PER_S, raw.t_ns / NS_PER_S + offset_s
    inside = (t_raw > t_gt[0]) & (t_raw < t_gt[-1])
    R_state = Slerp(t_gt, Rotation.from_quat(gt.quat_wxyz, scalar_first=True))(t_raw[inside])
    per_stamp = R_state.inv() * Rotation.from_quat(raw.quat_wxyz[inside], scalar_first=True)
    implied = per_stamp.mean()
    calib = seq.calibration.T_imu_frames.get(raw.frame) if seq.calibration is not None else None
    out = {"closed_form": angle(rec, closed), "euroc_state": angle(rec, implied),
           "euroc_state_spread": float(np.degrees(np.sqrt(np.mean((implied.inv() * per_stamp).magnitude() ** 2))))}
    if calib is not None:
        out["sensor_yaml"] = angle(rec, Rotation.from_matrix(np.asarray(calib)[:3, :3]))
    if seq.name.startswith("V1_"):
        v2g = Rotation.from_matrix(VICON2GT_R_IMU_POSE_V1)
        out["vicon2gt"], out["vicon2gt_vs_euroc_state"] = angle(rec, v2g), angle(v2g, implied)
    return out


# ----------------------------------------------------------------------------- recovery (child process)


def _recover_child(data: str, name: str, out_dir: str, overrides: dict, queue: mp.Queue) -> None:
    logging.basicConfig(level=logging.ERROR)
    from recovery.config import RecoveryConfig
    from recovery.recover import recover, write_recovery

    seq = load(Path(data), name)
    config = RecoveryConfig.from_dict(overrides)
    t0, c0 = time.perf_counter(), time.process_time()
    result = recover(seq, pose_stream=stream_of(name), config=config)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    write_recovery(result, out_dir)
    queue.put({"wall_s": wall, "cpu_s": cpu, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})


def recover_in_child(data: Path, name: str, out_dir: Path, overrides: dict) -> dict:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_recover_child, args=(str(data), name, str(out_dir), overrides, queue))
    proc.start()
    figures = queue.get()
    proc.join()
    return figures


# ----------------------------------------------------------------------------- one sequence


def measure(data: Path, name: str, work: Path, overrides: dict | None = None) -> dict:
    """Every figure of one sequence (see the module docstring)."""
    from recovery.outputs import RecoveryOutputs
    from validation.config import ValidationConfig
    from validation.sources import dataset_bias, read_bias_file
    from validation.validate import validate_inputs

    seq = load(data, name)
    stream = stream_of(name)
    rec_dir = work / name / "recovery"
    out = {"sequence": name, "stream": stream, **recover_in_child(data, name, rec_dir, overrides or {})}
    report = RecoveryOutputs.read(rec_dir).report.data
    bias_files = []
    if seq.ground_truth is None and name == "V1_01_easy":
        # EuRoC's own V1_01 bias exists for the first 5 s only: beside it every source would be judged on
        # those 4 windows, so the whole recording is judged beside OpenVINS's re-estimate instead
        bias_files = [("openvins", data / "euroc" / name / "ov_data" / f"{name}.csv")]
    elif seq.ground_truth is not None:
        bias_files = [("euroc", data / "euroc" / name / "mav0" / "state_groundtruth_estimate0" / "data.csv")]
    ref_stream = None if seq.ground_truth is not None else GT_POSES
    against_gt = validate_inputs(seq, recovery_dir=rec_dir, bias_files=bias_files, pose_stream=ref_stream,
                                 config=ValidationConfig(overlap=WINDOW_OVERLAP, crossval="off"))
    if stream == "vicon0":  # held out against the raw stream: judged
        held = validate_inputs(seq, recovery_dir=rec_dir, bias_files=bias_files, pose_stream=stream,
                               config=ValidationConfig(overlap=WINDOW_OVERLAP, crossval="auto"))
    else:  # positions only: held out against the ground truth
        held = validate_inputs(seq, recovery_dir=rec_dir, bias_files=bias_files, pose_stream=ref_stream,
                               config=ValidationConfig(overlap=WINDOW_OVERLAP, crossval="on"))
    raw = seq.poses[stream]
    independent = (independent_offset_rotation(raw, gt_poses(seq)) if raw.quat_wxyz is not None
                   else independent_offset_position(raw, gt_poses(seq), prism_lever_m(data, name)))
    out.update(report=report, against_gt=against_gt.to_dict(), held=held.to_dict(), independent_offset=independent)
    at_20_hz = raw if raw.quat_wxyz is None else raw.take(np.arange(0, len(raw.t_ns), 5))
    out["specific_force_offsets"] = [specific_force_offset(seq.imu, at_20_hz, f)[0] for f in SPECIFIC_FORCE_FILTERS_S]
    positions_alone = None
    if raw.quat_wxyz is None:
        out["ground_truth_positions_offset"] = _offset(recovery_of_positions(seq, gt_poses(seq)))
    else:
        positions_alone = recovery_of_positions(seq, raw)
        out["raw_positions_offset"] = _offset(positions_alone)
    if seq.ground_truth is not None:  # the other way round: EuRoC's bias against our trajectory
        ours, _ = read_tum_poses(rec_dir / "trajectory_tum.txt", source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
        swapped = load(data, name)
        swapped.poses["recovered_trajectory"] = ours
        swapped.ground_truth = None
        out["against_ours"] = validate_inputs(swapped, recovery_dir=rec_dir, bias_files=bias_files,
                                              pose_stream="recovered_trajectory",
                                              config=ValidationConfig(overlap=WINDOW_OVERLAP, crossval="off")).to_dict()
        if raw.quat_wxyz is not None:
            out["trajectory_agreement_mm"] = trajectory_agreement_mm(seq, raw, report, ours)
            out["mounting_deg"] = mounting_angles_deg(seq, raw, report)
        tracks = {"recovered": read_bias_file(rec_dir / "bias.csv"), "euroc": dataset_bias(seq)}
        if positions_alone is not None:
            tracks["positions_alone"] = positions_alone.outputs().bias
        out["preferred_tilt"] = preferred_tilt(seq, tracks)
        trajectories = {"recovered": ours}
        if positions_alone is not None:
            trajectories["positions_alone"] = positions_alone.outputs().trajectory
        out["attitude_offsets"] = attitude_offsets(seq, trajectories, tracks)
    return out


# ----------------------------------------------------------------------------- printing


def _sigmas(value: float, sigma: float | None, unit: str) -> str:
    """``value unit (z sigma of sigma unit)``; the sigma part only where there is one."""
    if sigma is None or not np.isfinite(sigma) or sigma <= 0:
        return f"{value:.2f} {unit}"
    return f"{value:.2f} {unit} ({value / sigma:.1f} sigma of {sigma:.3f} {unit})"


def _pair(src: dict, name: str) -> str:
    m = src.get(name)
    return "-" if m is None else f"{m['prmse_m']:.4f}/{m['roe_deg']:.3f}"


def _ratio(a: dict | None, b: dict | None, key: str) -> float:
    return float("nan") if a is None or b is None or not b[key] else a[key] / b[key]


def goals(m: dict) -> dict[str, bool | None]:
    """Each goal of the module docstring: True, False or None (does not apply)."""
    gt, held = m["against_gt"], m["held"]
    src, rec = gt["sources"], gt["sources"]["recovered"]
    euroc = src.get("euroc")
    heldout = held.get("heldout") or {}
    others = heldout.get("others_on_these_windows", {})
    h = held["sources"].get("recovered_heldout")
    state = euroc is not None and m["sequence"] != "V1_01_easy"
    out: dict[str, bool | None] = {"not FAIL": gt["verdict"] != "FAIL"}
    out["GT vs EuRoC"] = (_ratio(rec, euroc, "prmse_m") <= 1.1 and _ratio(rec, euroc, "roe_deg") <= 1.5) if state else None
    if m["stream"] == "vicon0" and "euroc" in others and h is not None:
        out["held out vs EuRoC"] = (h["prmse_m"] <= 1.1 * others["euroc"]["prmse_m"]
                                    and h["roe_deg"] <= 1.1 * others["euroc"]["roe_deg"])
    else:
        out["held out vs EuRoC"] = None
    out["held out beats constant, zero"] = (None if h is None else all(
        h["prmse_m"] < others[k]["prmse_m"] and h["roe_deg"] < others[k]["roe_deg"] for k in ("constant", "zero")))
    offset_ms = 1e3 * m["report"]["pose_time_offset_s"]
    out["offset within 5 ms"] = abs(offset_ms - 1e3 * m["independent_offset"][0]) <= 5.0
    middle = m["specific_force_offsets"][len(SPECIFIC_FORCE_FILTERS_S) // 2]
    out["offset within 5 ms of the rotation-free estimate"] = abs(offset_ms - 1e3 * middle) <= 5.0
    return out


def print_sequence(m: dict) -> None:
    r, gt, held = m["report"], m["against_gt"], m["held"]
    ext = r.get("extrinsic", {}).get("difference_from_calibration") or {}
    noise = r["noise"]
    pe = noise.get("pose_error") or {}
    print(f"\n== {m['sequence']} ({m['stream']}): {m['wall_s']:.1f} s wall, {m['cpu_s']:.1f} s CPU, "
          f"peak RSS {m['peak_rss_mb']:.0f} MB")
    print(f"  clock offset {1e3 * r['pose_time_offset_s']:+.2f} +- {1e3 * r['pose_time_offset_std_s']:.2f} ms "
          f"({r['pose_time_offset_method']}); independent {1e3 * m['independent_offset'][0]:+.2f} ms "
          + (f"(rotation-angle correlation {m['independent_offset'][1]:.3f})" if m["stream"] == "vicon0" else
             f"(prism track fit {1e3 * m['independent_offset'][1]:.1f} mm RMS)"))
    print("  rotation-free estimate (|specific force| of the positions at 20 Hz vs the accelerometer, no ground "
          "truth), Savitzky-Golay over " + "/".join(f"{f:g}" for f in SPECIFIC_FORCE_FILTERS_S) + " s: "
          + "/".join(f"{1e3 * x:+.1f}" for x in m["specific_force_offsets"]) + " ms")
    if "ground_truth_positions_offset" in m:
        off, sd = m["ground_truth_positions_offset"]
        print(f"  the same offset search on EuRoC's ground-truth positions alone (20 Hz, on the IMU clock): "
              f"{1e3 * off:+.2f} +- {1e3 * sd:.2f} ms")
    if "raw_positions_offset" in m:
        off, sd = m["raw_positions_offset"]
        print(f"  the position-only offset search on the stream's positions alone (20 Hz): {1e3 * off:+.2f} +- "
              f"{1e3 * sd:.2f} ms")
    if ext:
        print(f"  extrinsic vs sensor.yaml: {_sigmas(ext['rotation_deg'], ext['rotation_sigma_deg'], 'deg')}, "
              f"{_sigmas(100 * ext['translation_m'], 100 * (ext['translation_sigma_m'] or float('nan')), 'cm')}")
    print(f"  noise: gyro rw x{noise['gyro_random_walk_scale']:.3g}, acc rw x{noise['acc_random_walk_scale']:.3g}, "
          f"pose white {1e3 * noise['position_sigma_m']:.2f} mm / {1e3 * noise['rotation_sigma_rad']:.2f} mrad, "
          + ("correlated error none" if not pe else
             f"correlated {1e3 * pe['position_sigma_m']:.2f} mm tau {pe['position_tau_s']:g} s / "
             f"{1e3 * pe['rotation_sigma_rad']:.2f} mrad tau {pe['rotation_tau_s']:g} s")
          + f"; outliers {r['outliers_rejected']} of {r['pose_fusion'].get('samples_fused', r['keyframes'])}")
    g = r.get("gravity", {})
    print(f"  gravity {np.round(r['gravity_world_mps2'], 3).tolist()} ({(g.get('level_test') or {}).get('reason', 'estimated' if g.get('estimated') else 'given')})")
    print(f"  warnings: {len(r['warnings'])}" + "".join(f"\n    - {w}" for w in r["warnings"]))
    ref = gt["reference"]["kind"] + ("" if gt["reference"]["kind"] == "state" else f" {gt['reference'].get('stream')}")
    print(f"  against the ground truth ({ref}), PRMSE m / ROE deg, {gt['sources']['recovered']['windows']} windows: "
          f"verdict {gt['verdict']}")
    print("    " + "  ".join(f"{k} {_pair(gt['sources'], k)}" for k in gt["sources"]))
    heldout = held.get("heldout") or {}
    h = held["sources"].get("recovered_heldout")
    if h is not None:
        others = heldout.get("others_on_these_windows", {})
        where = "the raw stream" if m["stream"] == "vicon0" else "the ground truth"
        print(f"  held out (10-s blocks, 3 folds, against {where}; {heldout.get('windows')} windows, "
              f"{len(heldout.get('dropped_folds', []))} folds dropped): verdict {held['verdict']}"
              + (" (judged by the held-out blocks)" if heldout.get("judged") else ""))
        print(f"    recovered_heldout {h['prmse_m']:.4f}/{h['roe_deg']:.3f}  "
              + "  ".join(f"{k} {v['prmse_m']:.4f}/{v['roe_deg']:.3f}" for k, v in others.items()))
    if "against_ours" in m:
        agree = m.get("trajectory_agreement_mm")
        print(f"  against the recovered trajectory instead: recovered {_pair(m['against_ours']['sources'], 'recovered')}  "
              f"euroc {_pair(m['against_ours']['sources'], 'euroc')}"
              + ("" if agree is None else
                 f"; 1-s position second differences, RMS vs the raw stream: EuRoC's state {agree['ground_truth_vs_raw']:.2f} mm, "
                 f"recovered {agree['ours_vs_raw']:.2f} mm (between them {agree['ground_truth_vs_ours']:.2f} mm)"))
    if "preferred_tilt" in m:
        level = (r.get("gravity", {}).get("level_test") or {})
        print("  gravity each bias fits best against EuRoC's state (horizontal part; tilt from -z, PRMSE there / at "
              "nominal): " + "  ".join(f"{k} {v['tilt_deg']:.2f} deg {v['prmse_m']:.4f}/{v['prmse_nominal_m']:.4f}"
                                       for k, v in m["preferred_tilt"].items())
              + ("" if not level else f"; the recovery's tilt of the stream's frame {level['tilt_deg']:.2f} +- "
                 f"{level['tilt_std_deg']:.2f} deg"))
    if "mounting_deg" in m:
        print("  the IMU on the Vicon body (R_imu_pose), deg from the recovered one: "
              + ", ".join(f"{k} {v:.2f}" for k, v in m["mounting_deg"].items()))
    for k, a in m.get("attitude_offsets", {}).items():
        print(f"  EuRoC's attitude turned onto the {k} trajectory's (mean IMU-frame rotation, world frames tied by the positions: "
              f"tilt {a['tilt_deg']:.2f} deg, heading {a['heading_deg']:.2f} deg, spread {a['spread_deg']:.2f} deg RMS): "
              "PRMSE against EuRoC's state so turned " + "  ".join(f"{r} {v:.4f}" for r, v in a["prmse_m"].items()))
    print("  goals: " + ", ".join(f"{k}: {'-' if v is None else ('ok' if v else 'MISSED')}" for k, v in goals(m).items()))


def print_table(rows: list[dict]) -> None:
    print("\n| sequence | stream | offset ms (indep.) | extrinsic vs file | gyro/acc rw x | outliers | verdict | "
          "recovered PRMSE/ROE | EuRoC | held out | EuRoC held out | const held out | zero held out | s / MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for m in rows:
        r, gt, held = m["report"], m["against_gt"], m["held"]
        ext = r.get("extrinsic", {}).get("difference_from_calibration") or {}
        others = (held.get("heldout") or {}).get("others_on_these_windows", {})
        h = held["sources"].get("recovered_heldout")
        print(f"| {m['sequence']} | {m['stream']} | {1e3 * r['pose_time_offset_s']:+.1f} +- "
              f"{1e3 * r['pose_time_offset_std_s']:.2f} ({1e3 * m['independent_offset'][0]:+.1f}) | "
              + (f"{_sigmas(ext['rotation_deg'], ext['rotation_sigma_deg'], 'deg')}, "
                 f"{_sigmas(100 * ext['translation_m'], 100 * (ext['translation_sigma_m'] or float('nan')), 'cm')}"
                 if ext else "-")
              + f" | {r['noise']['gyro_random_walk_scale']:.3g}/{r['noise']['acc_random_walk_scale']:.3g} | "
              f"{r['outliers_rejected']} | {gt['verdict']} | {_pair(gt['sources'], 'recovered')} | "
              f"{_pair(gt['sources'], 'euroc')} | "
              + ("-" if h is None else f"{h['prmse_m']:.4f}/{h['roe_deg']:.3f}") + " | "
              + " | ".join(_pair(others, k) for k in ("euroc", "constant", "zero"))
              + f" | {m['wall_s']:.0f} / {m['peak_rss_mb']:.0f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--only", nargs="*", default=None, help="sequences (default: all nine)")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure to this file")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="recovery options other than the defaults (YAML values), e.g. noise_density_scales=[1]")
    args = ap.parse_args()
    try:
        overrides = assignments_to_mapping(args.set)
    except ConfigError as exc:
        sys.exit(str(exc))
    if not (args.data / "euroc").is_dir():
        sys.exit(f"no EuRoC data under {args.data}: set --data or BIASGT_SHARED_DATA")
    logging.basicConfig(level=logging.ERROR)
    names = args.only or [*VICON, *LEICA]
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for name in names:
            m = measure(args.data, name, Path(work), overrides)
            print_sequence(m)
            rows.append(m)
    print_table(rows)
    if args.json is not None:
        args.json.write_text(json.dumps([{k: v for k, v in m.items()} for m in rows], default=str, indent=1))


if __name__ == "__main__":
    main()
