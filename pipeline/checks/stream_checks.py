"""The checks of one stream: stamps, rates, non-finite rows, quaternions, IMU units and saturation.

Unit heuristics (documented rules, see :func:`detect_gyro_degps` and
:func:`detect_acc_in_g`):

* GYRO_DEGPS, first applicable rule wins:
    1. *pose rule*: when a pose stream with orientation (or the ground truth)
       overlaps the IMU and moves (90th percentile of its angular speed
       >= 0.1 rad/s), the ratio r = p90(|gyro|) / p90(pose angular speed) over the
       common span decides: deg/s if r > sqrt(180/pi) ~= 7.6 (the geometric
       middle between 1 and 57.3);
    2. *range rule*: p99(|gyro|) > 35 (35 rad/s = 2005 deg/s exceeds the full
       scale of any MEMS gyro, so such values can only be deg/s);
    3. *static rule*: in static stretches (0.5-s blocks whose |acc| varies by
       < 1 %), a median |mean gyro| > 1.0 is a bias no working gyro has in
       rad/s (57 deg/s) but an ordinary one in deg/s.
* ACC_IN_G: median |acc| in [0.8, 1.25] and 10th percentile >= 0.5 (gravity
  dominates, so the magnitude clusters around 1 g; gravity-removed data in
  m/s^2 has a 10th percentile near 0).

All checks are vectorised numpy: a 1-hour 200-Hz sequence (720000 rows) takes
well under a second.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pipeline.checks.options import G_MPS2, GROUND_TRUTH_STREAM, IMU_STREAM, MAX_LISTED, CheckOptions, Repair
from pipeline.checks.streams import (
    finite_rows,
    rel_s,
    round_or_none,
    row_norm,
    masked_rows,
    StreamView,
    time_order,
    TimeStats,
    pose_stream_label,
)
from pipeline.types import NS_PER_S, Finding, ImuSeries, Sequence, Severity


def check_stamps(s: StreamView, ts: TimeStats, opts: CheckOptions) -> list[Finding]:
    out: list[Finding] = []
    t = s.t_ns
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        rows = back + 1
        out.append(Finding(
            "NON_MONOTONIC", Severity.REPAIRABLE, s.name,
            f"{s.name} stamps go backwards {len(back)} times (first at row {int(rows[0])}, "
            f"t={float(rel_s(t[rows[0]], ts.t0_ns)):.3f} s); sort them with --repair {Repair.SORT.value}",
            {"count": int(len(back)), "first_rows": [int(i) for i in rows[:MAX_LISTED]],
             "first_t_s": [round_or_none(x) for x in rel_s(t[rows[:MAX_LISTED]], ts.t0_ns)],
             "max_backward_s": round_or_none(-float(dt[back].min()) / NS_PER_S)},
        ))
    n_dup = len(t) - len(ts.sorted_unique)
    if n_dup:
        if len(back):
            st = np.sort(t)
            dup_t = st[1:][np.diff(st) == 0]
        else:
            dup_t = t[1:][dt == 0]
        out.append(Finding(
            "DUPLICATE_STAMPS", Severity.REPAIRABLE, s.name,
            f"{s.name} has {n_dup} repeated stamps (first at t={float(rel_s(dup_t[0], ts.t0_ns)):.3f} s); "
            f"keep the first row of each with --repair {Repair.DROP_DUPLICATES.value}",
            {"count": int(n_dup), "first_t_s": [round_or_none(x) for x in rel_s(dup_t[:MAX_LISTED], ts.t0_ns)]},
        ))
    if len(ts.dt_ns) == 0 or not math.isfinite(ts.nominal_ns):
        return out
    nominal = ts.nominal_ns
    gap_idx = np.flatnonzero(ts.dt_ns > opts.gap_factor * nominal)
    if len(gap_idx):
        durations = ts.dt_ns[gap_idx] / NS_PER_S
        starts = ts.sorted_unique[gap_idx]
        longest = int(np.argmax(durations))
        out.append(Finding(
            "GAPS", Severity.WARNING, s.name,
            f"{s.name} has {len(gap_idx)} gaps longer than {opts.gap_factor:g}x its {nominal / 1e6:.3f} ms period "
            f"(longest {durations[longest]:.3f} s at t={float(rel_s(starts[longest], ts.t0_ns)):.3f} s); "
            + ("recover bridges them with the IMU alone (the bias sigma grows across them); cut the sequence there "
               "if the bias across them matters" if s.kind != "imu" else
               "results across gaps are less reliable, cut the sequence there if they are long"),
            {"count": int(len(gap_idx)), "nominal_period_ms": round_or_none(nominal / 1e6),
             "total_gap_s": round_or_none(float(durations.sum())),
             "gaps": [{"start_t_ns": int(a), "start_t_s": round_or_none(float(rel_s(a, ts.t0_ns))), "duration_s": round_or_none(d)}
                      for a, d in zip(starts[:MAX_LISTED], durations[:MAX_LISTED])]},
        ))
    dt_ms = ts.dt_ns / 1e6
    rate = NS_PER_S / nominal
    details: dict[str, Any] = {
        "rate_hz": round_or_none(rate), "nominal_period_ms": round_or_none(nominal / 1e6),
        "dt_std_ms": round_or_none(float(dt_ms.std())), "dt_min_ms": round_or_none(float(dt_ms.min())),
        "dt_max_ms": round_or_none(float(dt_ms.max())),
    }
    out.append(Finding(
        "RATE", Severity.INFO, s.name,
        f"{s.name} runs at {rate:.2f} Hz (step jitter std {details['dt_std_ms']:.3f} ms, max step "
        f"{details['dt_max_ms']:.3f} ms)",
        details,
    ))
    return out


def check_pose_rate(s: StreamView, ts: TimeStats, opts: CheckOptions) -> list[Finding]:
    """POSE_RATE_LOW: a pose stream sampled too sparsely to pin the bias down over 1-s windows."""
    if s.kind == "imu" or not math.isfinite(ts.nominal_ns) or ts.nominal_ns <= 0:
        return []
    rate = NS_PER_S / ts.nominal_ns
    if rate >= opts.min_pose_rate_hz:
        return []
    return [Finding(
        "POSE_RATE_LOW", Severity.WARNING, s.name,
        f"{s.name} runs at {rate:.3g} Hz, below {opts.min_pose_rate_hz:g} Hz: the bias between poses rests on the "
        "IMU alone and 1-s validation windows have few references; use the full-rate stream if there is one",
        {"rate_hz": round_or_none(rate), "min_pose_rate_hz": opts.min_pose_rate_hz},
    )]


def check_nonfinite(s: StreamView, valid: np.ndarray) -> list[Finding]:
    bad = np.flatnonzero(~valid)
    if not len(bad):
        return []
    if len(bad) == len(valid):
        return [Finding(
            "NONFINITE_ROWS", Severity.FATAL, s.name,
            f"every one of the {len(bad)} rows of {s.name} has NaN/inf values or a zero quaternion; "
            "check the column mapping and the input's units", {"count": int(len(bad)), "first_rows": [0]},
        )]
    return [Finding(
        "NONFINITE_ROWS", Severity.REPAIRABLE, s.name,
        f"{s.name} has {len(bad)} rows with NaN/inf values or a zero quaternion (first row {int(bad[0])}); "
        f"drop them with --repair {Repair.DROP_NONFINITE.value}",
        {"count": int(len(bad)), "first_rows": [int(i) for i in bad[:MAX_LISTED]]},
    )]


def check_quaternions(s: StreamView, valid: np.ndarray, opts: CheckOptions) -> list[Finding]:
    if s.quat is None:
        return []
    out: list[Finding] = []
    order = time_order(s.t_ns)
    q = masked_rows(s.quat[order], valid[order])
    if len(q) == 0:
        return out
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    dev = np.abs(norm - 1.0)
    max_dev = float(dev.max())
    if max_dev > opts.quat_norm_tol:
        out.append(Finding(
            "QUAT_NOT_UNIT", Severity.REPAIRABLE, s.name,
            f"{s.name} quaternion norms deviate from 1 by up to {max_dev:.3g} ({int((dev > opts.quat_norm_tol).sum())} "
            f"rows); normalise them with --repair {Repair.NORMALISE_QUATERNIONS.value}",
            {"max_deviation": round_or_none(max_dev, 9), "count": int((dev > opts.quat_norm_tol).sum()),
             "tolerance": opts.quat_norm_tol},
        ))
    if len(q) > 1:
        flips = int((np.einsum("ij,ij->i", q[1:], q[:-1]) < 0).sum())
        if flips:
            out.append(Finding(
                "QUAT_SIGN_FLIPS", Severity.INFO, s.name,
                f"{s.name} quaternions change sign {flips} times (q and -q are the same rotation); "
                f"make them continuous with --repair {Repair.CONTINUOUS_QUATERNIONS.value} if a tool needs it",
                {"count": flips},
            ))
    return out


def _pose_angular_speed(t_ns: np.ndarray, quat: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angular speed between consecutive valid, time-ordered poses: (mid stamps [M], speed rad/s [M])."""
    order = time_order(t_ns)
    t = masked_rows(t_ns[order], valid[order])
    q = masked_rows(quat[order], valid[order])
    q = q / row_norm(q)[:, None]
    dt = np.diff(t)
    keep = dt > 0
    if keep.sum() < 2:
        return np.empty(0, np.int64), np.empty(0)
    nominal = float(np.median(dt[keep]))
    keep &= dt <= 5 * nominal
    dot = np.clip(np.abs(np.einsum("ij,ij->i", q[1:], q[:-1])), 0.0, 1.0)
    angle = 2.0 * np.arccos(dot)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = angle / (dt / NS_PER_S)
    mid = t[:-1] + dt // 2
    return mid[keep], speed[keep]


def detect_gyro_degps(seq: Sequence, valid: np.ndarray | None = None) -> dict[str, Any] | None:
    """Decide whether the IMU gyro is in deg/s (rules in the module docstring).

    Args:
        seq: The sequence (its IMU and, for the pose rule, its oriented pose streams / ground truth).
        valid: Optional boolean [N] of usable IMU rows.

    Returns:
        ``None`` when the gyro looks like rad/s (or there is no IMU), else the
        details of the rule that fired (``rule`` plus its figures).
    """
    imu = seq.imu
    if imu is None or len(imu) < 2:
        return None
    if valid is None:
        valid = finite_rows(imu.gyro_radps) & finite_rows(imu.acc_mps2)
    t = masked_rows(imu.t_ns, valid)
    gyro = masked_rows(imu.gyro_radps, valid)
    gnorm = row_norm(gyro)
    if len(gnorm) < 2:
        return None
    # Rule 1: against the pose streams' angular speed.
    candidates: list[tuple[str, np.ndarray, np.ndarray]] = []
    if seq.ground_truth is not None:
        candidates.append((GROUND_TRUTH_STREAM, seq.ground_truth.t_ns, seq.ground_truth.quat_wxyz))
    for name, poses in seq.poses.items():
        if poses.quat_wxyz is not None:
            candidates.append((pose_stream_label(name), poses.t_ns, poses.quat_wxyz))
    for name, pt, pq in candidates:
        if len(pt) < 3:
            continue
        with np.errstate(invalid="ignore"):
            pvalid = finite_rows(pq) & (np.einsum("ij,ij->i", pq, pq) > 1e-2)
        mid, speed = _pose_angular_speed(pt, pq, pvalid)
        if len(mid) < 10:
            continue
        lo, hi = max(int(mid.min()), int(t.min())), min(int(mid.max()), int(t.max()))
        if hi <= lo:
            continue
        sp = speed[(mid >= lo) & (mid <= hi)]
        gi = gnorm[(t >= lo) & (t <= hi)]
        if len(sp) < 10 or len(gi) < 10:
            continue
        p90_pose = float(np.percentile(sp, 90))
        if p90_pose < 0.1:
            continue
        p90_gyro = float(np.percentile(gi, 90))
        ratio = p90_gyro / p90_pose
        if ratio > math.sqrt(180.0 / math.pi):
            return {"rule": "pose_rate_ratio", "pose_stream": name, "ratio": round_or_none(ratio, 3),
                    "gyro_p90": round_or_none(p90_gyro), "pose_rate_p90_radps": round_or_none(p90_pose)}
        return None  # the poses say rad/s: trust them over the magnitude rules
    # Rule 2: beyond any MEMS full scale in rad/s.
    p99 = float(np.percentile(gnorm, 99))
    if p99 > 35.0:
        return {"rule": "p99_magnitude", "gyro_p99": round_or_none(p99, 3), "threshold": 35.0}
    # Rule 3: static stretches with an absurd bias.
    rate = imu.rate_hz
    block = max(10, int(round(0.5 * rate))) if math.isfinite(rate) else 100
    nb = len(gnorm) // block
    if nb >= 2:
        anorm = row_norm(masked_rows(imu.acc_mps2, valid)[: nb * block]).reshape(nb, block)
        mean_a = anorm.mean(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            static = (anorm.std(axis=1) < 0.01 * mean_a) & (mean_a > 0)
        if static.sum() >= 2:
            gmean = gyro[: nb * block].reshape(nb, block, 3).mean(axis=1)[static]
            static_mag = float(np.median(row_norm(gmean)))
            if static_mag > 1.0:
                return {"rule": "static_magnitude", "static_gyro_magnitude": round_or_none(static_mag, 4),
                        "static_seconds": round_or_none(float(static.sum() * block / rate), 2), "threshold": 1.0}
    return None


def detect_acc_in_g(acc: np.ndarray) -> dict[str, Any] | None:
    """Decide whether accelerometer values [N, 3] are in g (rule in the module docstring).

    Returns:
        ``None`` when they do not look like g, else details (median and 10th percentile of |acc|).
    """
    n = row_norm(masked_rows(acc, finite_rows(acc)))
    if len(n) < 2:
        return None
    p10, med = (float(x) for x in np.percentile(n, [10, 50]))
    if 0.8 <= med <= 1.25 and p10 >= 0.5:
        return {"median_norm": round_or_none(med, 4), "p10_norm": round_or_none(p10, 4)}
    return None


def check_imu_units(seq: Sequence, valid: np.ndarray) -> list[Finding]:
    imu = seq.imu
    assert imu is not None
    out: list[Finding] = []
    g = detect_gyro_degps(seq, valid)
    if g is not None:
        out.append(Finding(
            "GYRO_DEGPS", Severity.REPAIRABLE, IMU_STREAM,
            f"gyro values look like deg/s, not rad/s (rule {g['rule']}); scale them by pi/180 with "
            f"--repair {Repair.GYRO_DEG_TO_RAD.value} (or --ignore GYRO_DEGPS if they are rad/s)",
            g,
        ))
    acc = masked_rows(imu.acc_mps2, valid)
    a = detect_acc_in_g(acc)
    if a is not None:
        out.append(Finding(
            "ACC_IN_G", Severity.REPAIRABLE, IMU_STREAM,
            f"accelerometer magnitude clusters at {a['median_norm']:.3f} (1 g), so values look like g, not m/s^2; "
            f"multiply by {G_MPS2} with --repair {Repair.ACC_G_TO_MPS2.value}",
            a,
        ))
    else:
        if len(acc) >= 2:
            med = float(np.median(row_norm(acc)))
            if not 4.0 <= med <= 20.0:
                out.append(Finding(
                    "ACC_SCALE_SUSPECT", Severity.WARNING, IMU_STREAM,
                    f"median |acc| is {med:.4g}, far from 9.81 m/s^2 (raw counts? gravity removed?); "
                    "give raw specific force in m/s^2",
                    {"median_norm": round_or_none(med, 4)},
                ))
    return out


def _saturated_axis(x: np.ndarray, min_count: int) -> dict[str, Any] | None:
    """Flat top at the largest |value| of one axis [N], or ``None``."""
    a = np.abs(x)
    if len(a) == 0:
        return None
    top = float(a.max())
    if not top > 0:
        return None
    at_top = a >= top * (1 - 1e-9)
    count = int(at_top.sum())
    if count < min_count:
        return None
    # A clipped axis piles up at the top: far more samples there than just below it (within 2 %),
    # and than at the next lower distinct level (the next quantisation step of a quantised sensor,
    # where a Gaussian tail has *more* samples than at its top).
    below = a[~at_top]
    band = int((below >= top * 0.98).sum())
    if len(below):
        next_level = float(below.max())
        next_count = int((below >= next_level * (1 - 1e-9)).sum())
    else:
        next_count = 0
    if count <= 2 * band or count <= 2 * next_count:
        return None  # a smooth peak or a noise tail, not a clipped one
    return {"value": round_or_none(top, 9), "count": count, "band_count": band, "next_level_count": next_count}


def check_saturation(imu: ImuSeries, valid: np.ndarray, opts: CheckOptions) -> list[Finding]:
    axes: dict[str, Any] = {}
    for prefix, arr in (("gyro", imu.gyro_radps), ("acc", imu.acc_mps2)):
        arr = masked_rows(arr, valid)
        for i, ax in enumerate("xyz"):
            hit = _saturated_axis(arr[:, i], opts.saturation_min_count)
            if hit is not None:
                axes[f"{prefix}_{ax}"] = hit
    if not axes:
        return []
    desc = ", ".join(f"{k} at |{v['value']:.4g}| x{v['count']}" for k, v in axes.items())
    return [Finding(
        "SATURATION", Severity.WARNING, IMU_STREAM,
        f"IMU axes sit at their extreme value ({desc}): the sensor range was exceeded there; "
        "cut those segments or record with a wider range",
        {"axes": axes, "count": int(sum(v["count"] for v in axes.values()))},
    )]
