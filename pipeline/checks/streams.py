"""Stream views: every stream of a :class:`~pipeline.types.Sequence` (IMU, pose streams, ground
truth) as stamps plus named value arrays, and the row and time statistics the checks share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.checks.options import GROUND_TRUTH_STREAM, IMU_STREAM
from pipeline.types import NS_PER_S, Sequence


@dataclass
class StreamView:
    """A uniform view of one time-stamped stream: stamps plus named value arrays."""

    name: str  # as shown: "imu", "poses/<stream>" (see pose_stream_label), "ground_truth"
    kind: str  # "imu", "poses", "ground_truth"
    t_ns: np.ndarray
    values: dict[str, np.ndarray]  # name -> [N, k]
    quat: np.ndarray | None
    obj: Any
    key: str = ""  # the sequence's own key of a pose stream (a topic keeps its leading '/')


def pose_stream_label(name: str) -> str:
    """How findings name a pose stream: ``poses/vicon0``, ``poses/odom`` for topic ``/odom`` (no ``//``)."""
    return f"poses/{name.lstrip('/')}"


def stream_views(seq: Sequence) -> list[StreamView]:
    out: list[StreamView] = []
    if seq.imu is not None:
        imu = seq.imu
        out.append(StreamView(IMU_STREAM, "imu", imu.t_ns, {"gyro": imu.gyro_radps, "acc": imu.acc_mps2}, None, imu))
    for name, poses in seq.poses.items():
        vals = {"p": poses.p_m}
        if poses.quat_wxyz is not None:
            vals["quat"] = poses.quat_wxyz
        out.append(StreamView(pose_stream_label(name), "poses", poses.t_ns, vals, poses.quat_wxyz, poses, key=name))
    if seq.ground_truth is not None:
        gt = seq.ground_truth
        vals = {"p": gt.p_m, "quat": gt.quat_wxyz, "v": gt.v_mps, "bg": gt.bias_gyro_radps, "ba": gt.bias_acc_mps2}
        out.append(StreamView(GROUND_TRUTH_STREAM, "ground_truth", gt.t_ns, vals, gt.quat_wxyz, gt))
    return out


def finite_rows(arr: np.ndarray) -> np.ndarray:
    """Boolean [N]: rows of ``arr`` [N, k] whose values are all finite (column sums: fast for small k)."""
    total = arr[:, 0].copy()
    for i in range(1, arr.shape[1]):
        total += arr[:, i]
    with np.errstate(invalid="ignore"):
        return np.isfinite(total)


def row_norm(arr: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of ``arr`` [N, k] -> [N]."""
    return np.sqrt(np.einsum("ij,ij->i", arr, arr))


def masked_rows(arr: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``arr[valid]`` without the copy when every row is valid."""
    return arr if valid.all() else arr[valid]


def time_order(t_ns: np.ndarray) -> np.ndarray | slice:
    """Index that orders ``t_ns`` by time (a no-op slice when it already is)."""
    if len(t_ns) < 2 or bool(np.all(t_ns[1:] >= t_ns[:-1])):
        return slice(None)
    return np.argsort(t_ns, kind="stable")


def valid_rows(s: StreamView) -> np.ndarray:
    """Boolean [N]: rows whose values are all finite and whose quaternion is not (near) zero."""
    ok = np.ones(len(s.t_ns), dtype=bool)
    for arr in s.values.values():
        ok &= finite_rows(arr)
    if s.quat is not None:
        with np.errstate(invalid="ignore"):
            ok &= np.einsum("ij,ij->i", s.quat, s.quat) > 1e-2
    return ok


def rel_s(t_ns: np.ndarray | int, t0_ns: int) -> Any:
    return (np.asarray(t_ns, dtype=np.int64) - t0_ns) / NS_PER_S


def round_or_none(x: float, nd: int = 6) -> float | None:
    x = float(x)
    return None if not math.isfinite(x) else round(x, nd)


@dataclass
class TimeStats:
    t0_ns: int
    t1_ns: int
    sorted_unique: np.ndarray
    dt_ns: np.ndarray  # positive steps of sorted_unique
    nominal_ns: float


def time_stats(t_ns: np.ndarray) -> TimeStats:
    if len(t_ns) > 1 and bool(np.all(t_ns[1:] > t_ns[:-1])):
        tu = t_ns
    else:
        tu = np.unique(t_ns)
    dt = np.diff(tu)
    nominal = float(np.median(dt)) if len(dt) else float("nan")
    return TimeStats(int(tu[0]) if len(tu) else 0, int(tu[-1]) if len(tu) else 0, tu, dt, nominal)
