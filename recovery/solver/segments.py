"""Overlapping segments for long recordings, and their stitching.

A recording is cut into segments of ``segment_s`` that overlap by
``overlap_s``; each is solved on its own (memory and time bounded by the
segment, total time linear in duration). In an overlap both solutions exist at
the same keyframes; the bias, its std and the trajectory are blended with a
weight that ramps linearly from the earlier to the later segment, so there is
no step at a boundary. The std is blended the same way (the edge of a segment
is slightly less certain than its middle: blending keeps the std honest where
either solution alone would be over- or under-confident).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.types import NS_PER_S
from recovery.solver.window import WindowSolution


def plan_segments(t0_ns: int, t1_ns: int, segment_s: float, overlap_s: float) -> list[tuple[int, int]]:
    """Segment bounds ``[(start_ns, end_ns)]`` covering ``[t0_ns, t1_ns]``.

    Consecutive segments overlap by at least ``overlap_s``; the last one ends at
    ``t1_ns``. A span shorter than ``1.5 * segment_s`` is one segment.
    """
    span = (t1_ns - t0_ns) / NS_PER_S
    if span <= 1.5 * segment_s:
        return [(int(t0_ns), int(t1_ns))]
    step = segment_s - overlap_s
    n = int(np.ceil((span - overlap_s) / step))
    out = []
    for i in range(n):
        a = t0_ns + int(round(i * step * NS_PER_S))
        b = min(a + int(round(segment_s * NS_PER_S)), t1_ns)
        if i == n - 1:
            b = t1_ns
        out.append((int(a), int(b)))
    return out


@dataclass
class Stitched:
    """Concatenated per-keyframe result of several segment solutions."""

    t_ns: np.ndarray
    bias: np.ndarray
    bias_std: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    seam_jumps: list[dict[str, float]]


def _slerp_wxyz(qa: np.ndarray, qb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-row slerp from qa to qb (wxyz, [M, 4]) by weights w [M]."""
    ra = Rotation.from_quat(np.c_[qa[:, 1:], qa[:, :1]])
    rb = Rotation.from_quat(np.c_[qb[:, 1:], qb[:, :1]])
    rel = (ra.inv() * rb).as_rotvec()
    q = (ra * Rotation.from_rotvec(rel * w[:, None])).as_quat()
    return np.c_[q[:, 3:], q[:, :3]]


def stitch(solutions: list[WindowSolution]) -> Stitched:
    """Blend consecutive, time-ordered segment solutions in their overlaps.

    Keyframes shared by two segments (same stamps) get the blend; keyframes of
    one segment only are copied. ``seam_jumps`` reports, per boundary, the largest
    |difference| of the two solutions at the blend's midpoint divided by the
    combined std (a seam check).
    """
    if len(solutions) == 1:
        s = solutions[0]
        return Stitched(s.t_ns, s.bias, s.bias_std, s.p_m, s.quat_wxyz, s.v_mps, [])
    parts = {k: [] for k in ("t_ns", "bias", "bias_std", "p_m", "quat_wxyz", "v_mps")}
    seams = []
    cur = solutions[0]
    cur_sel = np.ones(len(cur.t_ns), dtype=bool)
    for nxt in solutions[1:]:
        common, ia, ib = np.intersect1d(cur.t_ns, nxt.t_ns, assume_unique=True, return_indices=True)
        if len(common) == 0:
            for k in parts:
                parts[k].append(getattr(cur, k)[cur_sel])
            cur, cur_sel = nxt, np.ones(len(nxt.t_ns), dtype=bool)
            continue
        # the part of cur before the overlap
        before = cur_sel & (cur.t_ns < common[0])
        for k in parts:
            parts[k].append(getattr(cur, k)[before])
        span = max(int(common[-1] - common[0]), 1)
        w = ((common - common[0]) / span)[:, None]
        parts["t_ns"].append(common)
        parts["bias"].append((1 - w) * cur.bias[ia] + w * nxt.bias[ib])
        parts["bias_std"].append((1 - w) * cur.bias_std[ia] + w * nxt.bias_std[ib])
        parts["p_m"].append((1 - w) * cur.p_m[ia] + w * nxt.p_m[ib])
        parts["v_mps"].append((1 - w) * cur.v_mps[ia] + w * nxt.v_mps[ib])
        parts["quat_wxyz"].append(_slerp_wxyz(cur.quat_wxyz[ia], nxt.quat_wxyz[ib], w[:, 0]))
        mid = len(common) // 2
        comb = np.sqrt(cur.bias_std[ia[mid]] ** 2 + nxt.bias_std[ib[mid]] ** 2)
        diff = np.abs(cur.bias[ia[mid]] - nxt.bias[ib[mid]])
        z = diff / comb
        # without marginals (calibration solves) the seam cannot be judged: NaN
        seams.append({"t_ns": int(common[mid]),
                      "max_abs_diff_over_sigma": float(np.nanmax(z)) if np.isfinite(z).any() else float("nan")})
        cur = nxt
        cur_sel = nxt.t_ns > common[-1]
    for k in parts:
        parts[k].append(getattr(cur, k)[cur_sel])
    out = {k: np.concatenate(v, axis=0) for k, v in parts.items()}
    return Stitched(out["t_ns"], out["bias"], out["bias_std"], out["p_m"], out["quat_wxyz"], out["v_mps"], seams)
