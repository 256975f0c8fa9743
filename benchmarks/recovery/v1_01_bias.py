"""V1_01: which accelerometer bias do the IMU readings support, EuRoC's (ba_y ~0.55) or OpenVINS's (~0.145)?

    .venv/bin/python benchmarks/recovery/v1_01_bias.py [--data DIR] [--block-s 10] [--folds 3]

A bias means something only together with the frame it is expressed against: a tilt of the
reference attitude and an accelerometer bias trade off (0.4 m/s^2 is a ~2.3 deg tilt). So every
candidate below is a bias AND a frame (the pose-to-IMU rotation, and the gravity vector in the pose
world), and the arbiter is the 1-s integration error (validation's metric, PRMSE / ROE) on poses the
bias was not fitted to:

* biasgt's recoveries are cross-validated by time blocks (:mod:`validation.crossval.blocks`): recovered
  without the poses of one fold of ``--block-s`` blocks, judged on that fold's windows, so every
  window is held out; against the stream they were fitted to, each fold's own estimated extrinsic
  and gravity are used;
* EuRoC's estimate (a sequence constant, ``state_groundtruth_estimate0`` of the first 5 s) and
  OpenVINS's re-estimated bias (``ov_data/V1_01_easy.csv``) are judged on the same windows with the
  pose stream as given (identity extrinsic, gravity ``-9.81 z``);
* every candidate is also judged against the OTHER pose source, taken as given.

Pose sources: EuRoC's ground-truth poses (``ov_data/V1_01_easy_original.txt``, 200 Hz, Vicon +
hand-eye) and OpenVINS's re-estimated poses (``ov_data/V1_01_easy.csv``, 20 Hz, IMU frame). The
script also prints the ground-truth-to-IMU rotation estimated by the recovery (``extrinsic: estimate``)
with its sigma, and the attitude difference between the two pose sources (gravity direction in the
body frame), then a verdict derived from these numbers.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # the project's packages before this folder's scripts

from pipeline.errors import BiasgtError  # noqa: E402
from pipeline.io import load_sequence  # noqa: E402
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, Sequence  # noqa: E402
from recovery.config import ExtrinsicMode, IntrinsicsMode, RecoveryConfig  # noqa: E402
from recovery.recover import RecoveryResult, recover  # noqa: E402
from validation.config import ValidationConfig  # noqa: E402
from validation.crossval.blocks import (  # noqa: E402
    BlockFolds,
    CrossValidatedBias,
    crossvalidate_recovery,
    held_constant,
    imu_and_bias_of,
)
from validation.crossval.heldout import HeldOutErrors, held_out_errors, held_out_windows  # noqa: E402
from validation.validate import WindowPlan, plan_windows, read_bias_file, reference_from_poses  # noqa: E402

DEFAULT_DATA = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data"))
GT, OV = "groundtruth_poses", "openvins"
STREAMS = {GT: "EuRoC GT poses", OV: "OpenVINS poses"}
NOMINAL_G = np.array([0.0, 0.0, -9.81])
SEQ = "euroc/V1_01_easy"
OV_FILE = f"{SEQ}/ov_data/V1_01_easy.csv"
GT_FILE = f"{SEQ}/ov_data/V1_01_easy_original.txt"
EUROC_STATE = "euroc/V1_01_easy_proto_excerpt/mav0/state_groundtruth_estimate0/data.csv"


@dataclass(frozen=True)
class Frame:
    """What a candidate's bias is expressed against, for one pose stream: ``T_imu_pose`` and gravity."""

    T_imu_pose: np.ndarray
    gravity_mps2: np.ndarray


def frame_of(r: RecoveryResult) -> Frame:
    """The frame a recovery estimated its bias against: its extrinsic and gravity."""
    return Frame(r.report.T_imu_pose, np.asarray(r.report.gravity_world_mps2, dtype=float))


NOMINAL = Frame(np.eye(4), NOMINAL_G)  # a pose stream as given


@dataclass
class Candidate:
    """A bias at the IMU stamps; for biasgt's, the stream fitted, each fold's frame and the full-data recovery."""

    name: str
    how: str
    bias: np.ndarray  # [N, 6]
    imu: ImuSeries  # the readings to integrate (corrected when intrinsics were estimated)
    fitted_to: str | None = None
    fold_frames: list[Frame] = field(default_factory=list)
    recoveries: tuple = ()
    full: RecoveryResult | None = None


@dataclass(frozen=True)
class Spec:
    """A biasgt candidate: the stream it is recovered from and the recovery options."""

    name: str
    how: str
    stream: str
    config: RecoveryConfig


SPECS = (
    Spec("biasgt_gt", "biasgt from GT poses, extrinsic known (identity)", GT, RecoveryConfig()),
    Spec("biasgt_gt_ext", "biasgt from GT poses, GT-to-IMU extrinsic estimated", GT,
         RecoveryConfig(extrinsic_mode=ExtrinsicMode.ESTIMATE)),
    Spec("biasgt_gt_ext_intr", "biasgt from GT poses, extrinsic + IMU intrinsics (with g-sensitivity) estimated",
         GT, RecoveryConfig(extrinsic_mode=ExtrinsicMode.ESTIMATE, intrinsics=IntrinsicsMode.WITH_G_SENSITIVITY)),
    Spec("biasgt_ov", "biasgt from OpenVINS poses, extrinsic known (identity)", OV, RecoveryConfig()),
    Spec("biasgt_ov_ext", "biasgt from OpenVINS poses, extrinsic estimated", OV,
         RecoveryConfig(extrinsic_mode=ExtrinsicMode.ESTIMATE)),
)


def load(data: Path) -> Sequence:
    """V1_01: IMU (mav0), EuRoC GT poses and OpenVINS poses as two streams; exits when the data are absent."""
    root = data / SEQ
    missing = [f for f in (root / "mav0/imu0/data.csv", data / GT_FILE, data / OV_FILE, data / EUROC_STATE)
               if not f.is_file()]
    if missing:
        sys.exit(f"v1_01_bias: the real data folder is absent or incomplete ({missing[0]} not found); "
                 "give --data DIR or set BIASGT_SHARED_DATA")
    return load_sequence(root, extra_poses=[
        {"path": str(data / GT_FILE), "stream": GT, "kind": "ground_truth"},
        {"path": str(data / OV_FILE), "stream": OV, "kind": "ground_truth"}])


def file_candidate(name: str, how: str, path: Path, imu: ImuSeries) -> Candidate:
    """A bias file at the IMU stamps, ends held (EuRoC's is a sequence constant given over 5 s)."""
    track = read_bias_file(path)
    x = (track.t_ns - track.t_ns[0]).astype(float)
    xq = (imu.t_ns - track.t_ns[0]).astype(float)
    bias = np.stack([np.interp(xq, x, track.bias[:, c]) for c in range(6)], axis=1)
    return Candidate(name, how, bias, imu)


def recovered_candidate(spec: Spec, seq: Sequence, folds: BlockFolds) -> Candidate:
    """Cross-validated by blocks (:func:`validation.crossval.blocks.crossvalidate_recovery`), plus the full-data recovery."""
    def rec(s: Sequence, stream: str) -> RecoveryResult:
        return recover(s, pose_stream=stream, config=spec.config)

    cv = crossvalidate_recovery(seq, spec.stream, folds, rec)
    frames = [frame_of(r) for r in cv.recoveries]
    return Candidate(spec.name, spec.how, cv.bias, cv.imu, spec.stream, frames, cv.recoveries, rec(seq, spec.stream))


CONSTANT_OF = ("biasgt_gt", "biasgt_ov")  # also judged held constant per fold (like EuRoC's sequence constant)


def constant_candidate(c: Candidate, imu: ImuSeries, folds: BlockFolds) -> Candidate:
    """``c``'s folds held constant (:func:`validation.crossval.blocks.held_constant`), in the same frames."""
    cv = held_constant(CrossValidatedBias(c.imu, c.bias, c.recoveries), imu, folds)
    return Candidate(f"{c.name}_const", f"{c.name}'s fold recoveries, each held constant (its mean)", cv.bias, cv.imu,
                     c.fitted_to, c.fold_frames, c.recoveries)


def errors(cand: Candidate, seq: Sequence, stream: str, folds: BlockFolds, plan: WindowPlan, refs: dict,
           cfg: ValidationConfig) -> HeldOutErrors:
    """Held-out errors of a candidate against a stream, fold by fold (each fold in its own frame)."""
    pos, rot = [], []
    fold_of_start = folds.fold(seq.imu.t_ns[plan.starts])
    for k in range(folds.n_folds):
        frame = cand.fold_frames[k] if cand.fitted_to == stream else NOMINAL
        key = (stream, frame.T_imu_pose.tobytes())
        if key not in refs:
            refs[key] = reference_from_poses(seq.poses[stream], seq.imu.t_ns, T_imu_pose=frame.T_imu_pose)
        ref = refs[key]
        win = held_out_windows(seq.imu, plan, folds, ref) & (fold_of_start == k)
        e = held_out_errors(cand.imu, cand.bias, ref, plan, win, frame.gravity_mps2, cfg)
        pos.append(e.pos_err_m)
        rot.append(e.rot_err_deg)
    return HeldOutErrors(np.concatenate(pos), np.concatenate(rot))


def attitude_difference_deg(seq: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """Mean small rotation (deg, body axes) taking the up direction in the GT body frame to that in the OpenVINS
    body frame, and the acc-bias difference it implies, EuRoC's minus OpenVINS's (m/s^2, ``|g| (u_ov - u_gt)``):
    at rest ``f = |g| u + b`` with ``u = R^T z`` the up direction in the body frame."""
    a, b = seq.poses[GT], seq.poses[OV]
    t = np.arange(max(a.t_ns[0], b.t_ns[0]) + NS_PER_S, min(a.t_ns[-1], b.t_ns[-1]) - NS_PER_S, NS_PER_S // 20)

    def up_in_body(p: PoseSeries) -> np.ndarray:
        rot = Rotation.from_quat(p.quat_wxyz, scalar_first=True)
        return Slerp((p.t_ns - p.t_ns[0]) / NS_PER_S, rot)((t - p.t_ns[0]) / NS_PER_S).inv().apply([0.0, 0.0, 1.0])

    ua, ub = up_in_body(a), up_in_body(b)
    return np.degrees(np.cross(ua, ub).mean(axis=0)), -NOMINAL_G[2] * (ub - ua).mean(axis=0)


def rotation_deg(r: RecoveryResult) -> tuple[np.ndarray, np.ndarray | None]:
    """The recovery's imu<-pose rotation as a rotation vector (deg) and its sigma (deg; None when given)."""
    sd = (r.report.get("extrinsic") or {}).get("rotation_std_deg")
    return (np.degrees(Rotation.from_matrix(r.report.T_imu_pose[:3, :3]).as_rotvec()),
            None if sd is None else np.asarray(sd, dtype=float))


def measure(data: Path, block_s: float = 10.0, n_folds: int = 3, specs: tuple[Spec, ...] = SPECS) -> dict:
    """Every candidate's held-out errors against both pose streams, and the frame figures.

    Returns:
        ``{"sequence", "candidates": [Candidate], "errors": {name: {stream: HeldOutErrors}}, "in_sample_mm":
        {name: PRMSE of the full-data recovery against its own stream}, "folds": BlockFolds, "attitude_deg": [3],
        "attitude_bias_mps2": [3]}``.
    """
    seq = load(data)
    imu = seq.imu
    folds = BlockFolds(int(imu.t_ns[0]), block_s, n_folds)
    cands = [file_candidate("euroc", "EuRoC's estimate (state_groundtruth_estimate0, a sequence constant)",
                            data / EUROC_STATE, imu),
             file_candidate("openvins", "OpenVINS's re-estimated state (ov_data/V1_01_easy.csv)", data / OV_FILE, imu)]
    recovered = [recovered_candidate(spec, seq, folds) for spec in specs]
    cands += recovered + [constant_candidate(c, imu, folds) for c in recovered if c.name in CONSTANT_OF]
    cfg = ValidationConfig()
    plan = plan_windows(imu, cfg)
    refs: dict = {}
    table = {c.name: {s: errors(c, seq, s, folds, plan, refs, cfg) for s in STREAMS} for c in cands}
    own = {c.name: 1e3 * in_sample(c, seq, folds, plan, refs, cfg).prmse_m for c in cands if c.full is not None}
    att, att_bias = attitude_difference_deg(seq)
    return {"sequence": seq, "candidates": cands, "errors": table, "in_sample_mm": own, "folds": folds,
            "attitude_deg": att, "attitude_bias_mps2": att_bias}


def fmt_vec(v: np.ndarray, scale: float = 1.0, prec: int = 3) -> str:
    return "(" + ", ".join(f"{x * scale:+.{prec}f}" for x in v) + ")"


def in_sample(c: Candidate, seq: Sequence, folds: BlockFolds, plan: WindowPlan, refs: dict,
              cfg: ValidationConfig) -> HeldOutErrors:
    """The full-data recovery's errors on the same windows against the stream it was fitted to (NOT held out)."""
    imu, bias = imu_and_bias_of(seq.imu, c.full)
    full = Candidate(c.name, c.how, bias, imu, c.fitted_to, [frame_of(c.full)] * folds.n_folds)
    return errors(full, seq, c.fitted_to, folds, plan, refs, cfg)


def verdict(m: dict) -> str:
    """One paragraph derived from the figures of :func:`measure`."""
    e = {n: {s: (v.prmse_m * 1e3) for s, v in d.items()} for n, d in m["errors"].items()}
    by = {c.name: c for c in m["candidates"]}
    mean_ba = {n: np.nanmean(c.bias[:, 3:], axis=0) for n, c in by.items()}
    obs = mean_ba["euroc"] - mean_ba["openvins"]
    pred = m["attitude_bias_mps2"]
    own = e["euroc"][GT] < e["openvins"][GT] and e["openvins"][OV] < e["euroc"][OV]
    parts = [
        f"Each bias fits the attitude it was estimated with: against EuRoC's poses EuRoC's bias (ba_y "
        f"{mean_ba['euroc'][1]:.3f}) integrates to a held-out PRMSE of {e['euroc'][GT]:.1f} mm and OpenVINS's "
        f"(ba_y {mean_ba['openvins'][1]:.3f}) to {e['openvins'][GT]:.1f} mm; against OpenVINS's poses "
        + ("the order reverses" if own else "the order is the same")
        + f" ({e['openvins'][OV]:.1f} vs {e['euroc'][OV]:.1f} mm).",
        f"The two sources' attitudes differ by {fmt_vec(m['attitude_deg'], prec=2)} deg (up direction in the body "
        f"frame), which predicts a bias difference EuRoC minus OpenVINS of {fmt_vec(pred)} m/s^2 against the "
        f"observed {fmt_vec(obs)}: the ba_y gap is {100 * pred[1] / obs[1]:.0f} % a difference of frame.",
    ]
    if "biasgt_gt_ext" in by and by["biasgt_gt_ext"].full is not None:
        rv, sd = rotation_deg(by["biasgt_gt_ext"].full)
        spread = np.std([rotation_deg(r)[0] for r in by["biasgt_gt_ext"].recoveries], axis=0, ddof=1)
        parts.append(
            f"The GT-to-IMU rotation estimated from the data (rates and specific force) is {fmt_vec(rv, prec=2)} deg "
            f"+- {fmt_vec(sd, prec=3)} (spread over the folds {fmt_vec(spread, prec=2)}), far from the "
            f"{np.degrees(obs[1] / -NOMINAL_G[2]):.1f} deg about z that would turn one bias into the other; with it "
            f"ba_y is {mean_ba['biasgt_gt_ext'][1]:.3f} and the held-out PRMSE against the GT poses "
            f"{e['biasgt_gt_ext'][GT]:.1f} mm ({'better' if e['biasgt_gt_ext'][GT] < e['biasgt_gt'][GT] else 'worse'} "
            f"than {e['biasgt_gt'][GT]:.1f} mm with the identity).")
    if "biasgt_gt_ext_intr" in by:
        gi = e["biasgt_gt_ext_intr"]
        parts.append(
            f"Freeing the IMU intrinsics as well moves ba_y to {mean_ba['biasgt_gt_ext_intr'][1]:.3f} (a rotation "
            f"of the accelerometer axes against the gyro's), held-out {gi[GT]:.1f} mm against the GT poses and "
            f"{gi[OV]:.1f} mm against OpenVINS's: "
            + ("no better than the plain recovery against the GT poses, so the data do not ask for it."
               if gi[GT] >= e["biasgt_gt"][GT] else "better against the GT poses."))
    if "biasgt_gt_const" in e:
        const, varying = e["biasgt_gt_const"][GT], e["biasgt_gt"][GT]
        parts.append(
            f"biasgt's GT-pose recovery integrates to {varying:.1f} mm on held-out blocks (far above its in-sample "
            f"{m['in_sample_mm']['biasgt_gt']:.1f} mm) and to {const:.1f} mm held constant per fold, against "
            f"{e['euroc'][GT]:.1f} mm for EuRoC's sequence constant: "
            + ("its variation over time does not carry to unseen blocks (it follows the poses more than the sensor)."
               if const <= varying else "its variation over time carries to unseen blocks."))
    best_gt = min(e, key=lambda n: e[n][GT])
    parts.append(
        f"The only attitude measured independently of the accelerometer is the Vicon one (OpenVINS's tilt comes from "
        f"the same accelerometer, through its VIO), so the bias consistent with these IMU readings is the one that "
        f"integrates best against EuRoC's poses: '{best_gt}' (ba_y {mean_ba[best_gt][1]:.3f}, "
        f"{e[best_gt][GT]:.1f} mm), "
        f"expressed in EuRoC's ground-truth frame; OpenVINS's {mean_ba['openvins'][1]:.3f} is consistent only with "
        f"OpenVINS's own, {abs(m['attitude_deg'][2]):.1f}-deg different, attitude.")
    return " ".join(parts)


def report(m: dict) -> None:
    folds, table = m["folds"], m["errors"]
    print(f"V1_01: held-out 1-s integration error (validation's metric), {folds.n_folds} folds of {folds.block_s:g}-s "
          "blocks, windows wholly inside a block")
    head = "".join(f"{STREAMS[s] + ': PRMSE mm / ROE deg':>38s}" for s in STREAMS)
    print(f"{'candidate':19s} {'ba mean (m/s^2)':26s} {'bg mean (mrad/s)':26s}{head}   {'in-sample own':>14s}   "
          "rotation imu<-pose, full data (deg) +- sigma")
    for c in m["candidates"]:
        cells = "".join(f"{1e3 * table[c.name][s].prmse_m:>25.1f} / {table[c.name][s].roe_deg:.3f} "
                        f"(n={len(table[c.name][s].pos_err_m)})" for s in STREAMS)
        own = rot = ""
        if c.full is not None:
            own = f"{m['in_sample_mm'][c.name]:.1f}"
            rv, sd = rotation_deg(c.full)
            rot = fmt_vec(rv, prec=3) + (" given" if sd is None else " +- " + fmt_vec(sd))
        print(f"{c.name:19s} {fmt_vec(np.nanmean(c.bias[:, 3:], 0)):26s} "
              f"{fmt_vec(np.nanmean(c.bias[:, :3], 0), 1e3, 2):26s}{cells}   {own:>14s}   {rot}")
    print("Frames (gravity and extrinsic of each integration): against the stream a biasgt candidate was fitted to, "
          "each fold's own estimated extrinsic and gravity (below); every other cell: the stream as given, "
          "identity extrinsic and g = (0, 0, -9.81).")
    for c in m["candidates"]:
        print(f"  {c.name}: {c.how}")
        if c.full is None:
            continue  # a file's bias, or a constant candidate (its parent's folds and frames)
        for k, r in enumerate(c.recoveries):
            rv, sd = rotation_deg(r)
            g = np.asarray(r.report.gravity_world_mps2, dtype=float)
            tilt = np.degrees(np.arctan2(np.linalg.norm(g[:2]), -g[2]))
            given = " (given)" if sd is None else f" +- {fmt_vec(sd)}"
            print(f"    fold {k}: rotation imu<-pose {fmt_vec(rv)} deg{given}"
                  + f"; gravity {fmt_vec(g)} m/s^2 (tilt {tilt:.2f} deg); "
                  f"acc random walk {r.report['noise']['acc_random_walk_scale']:.3g}x")
    print(f"Attitude of OpenVINS's poses against EuRoC's (up direction in the body frame): "
          f"{fmt_vec(m['attitude_deg'])} deg, implying acc bias EuRoC minus OpenVINS "
          f"{fmt_vec(m['attitude_bias_mps2'])} m/s^2")
    print()
    print("Verdict: " + verdict(m))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the shared data folder (default: %(default)s)")
    ap.add_argument("--block-s", type=float, default=10.0, help="cross-validation block length, s (default 10)")
    ap.add_argument("--folds", type=int, default=3, help="number of folds (default 3)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    t0 = time.perf_counter()
    try:
        report(measure(args.data, args.block_s, args.folds))
    except BiasgtError as exc:
        sys.exit(f"v1_01_bias: {exc}")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
