"""Repairs of a checked sequence: :func:`parse_repairs` (the ``--repair`` list) and
:func:`apply_repairs`, which applies only the repairs the user allows.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

import numpy as np

from pipeline.checks.options import DEG_TO_RAD, G_MPS2, CheckOptions, Repair
from pipeline.checks.stream_checks import detect_acc_in_g, detect_gyro_degps
from pipeline.checks.stamp_unit import scaled_stamps, stamp_unit
from pipeline.checks.streams import (
    StreamView,
    finite_rows,
    masked_rows,
    pose_stream_label,
    stream_views,
    time_stats,
    valid_rows,
)
from pipeline.errors import ConfigError
from pipeline.types import ImuSeries, Sequence

log = logging.getLogger(__package__)  # findings and repairs log as one: 'pipeline.checks'


def parse_repairs(spec: str | Iterable[str | Repair] | None) -> set[Repair]:
    """Repairs from ``"sort,drop-duplicates"``, ``"all"``, ``"none"`` or an iterable of names / :class:`Repair`.

    Raises:
        ConfigError: For an unknown repair name.
    """
    if spec is None:
        return set()
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out: set[Repair] = set()
    for item in items:
        if isinstance(item, Repair):
            out.add(item)
            continue
        name = str(item).strip().lower().replace("_", "-")
        if not name or name == "none":
            continue
        if name == "all":
            out |= set(Repair)
            continue
        try:
            out.add(Repair(name))
        except ValueError:
            raise ConfigError(f"unknown repair '{item}'", field="--repair",
                              hint="use a comma list of " + ", ".join(r.value for r in Repair) + ", or 'all'") from None
    return out


def _replace_stream(obj: Any, **arrays: np.ndarray) -> Any:
    if isinstance(obj, ImuSeries):
        return ImuSeries(obj.t_ns, arrays.get("gyro_radps", obj.gyro_radps), arrays.get("acc_mps2", obj.acc_mps2),
                         obj.temperature_degc)
    return replace(obj, **arrays)


def apply_repairs(seq: Sequence, repairs: Iterable[Repair | str], options: CheckOptions | None = None
                  ) -> tuple[Sequence, list[str]]:
    """Apply the allowed repairs to every stream; ``seq`` is not modified.

    Order: stamps to nanoseconds, drop non-finite rows and placeholder poses, sort, drop duplicates (keeps
    the first row of each stamp), normalise quaternions, make them continuous, IMU unit scaling, positions
    to metres. The unit repairs are applied only where their check fires (so ``--repair all`` leaves
    correct data alone) and not when the user ignores that code.

    Args:
        seq: The sequence.
        repairs: The allowed repairs.
        options: Check options (its ``ignore`` set matters for the unit repairs).

    Returns:
        ``(new_sequence, changes)``: ``changes`` says what was changed, with counts;
        it is appended to ``new_sequence.metadata["repairs"]``.
    """
    allowed = parse_repairs(repairs)
    opts = options or CheckOptions()
    changes: list[str] = []
    imu, poses, gt = seq.imu, dict(seq.poses), seq.ground_truth

    views = stream_views(seq)
    t0s = {s.name: int(np.min(s.t_ns)) for s in views if len(s.t_ns) >= 2}
    for s in views:
        if len(s.t_ns) == 0:
            continue
        obj = _fix_stamp_unit(s, [t for n, t in t0s.items() if n != s.name], allowed, opts, changes)
        obj = _fix_rows(s.name, obj, valid_rows(s), allowed, changes)
        if s.kind != "imu":
            obj = _fix_placeholders(s.name, obj, allowed, opts, changes)
            obj = _fix_quat(s.name, obj, allowed, opts, changes)
        if s.kind == "imu":
            imu = obj
        elif s.kind == "poses":
            poses[s.key] = obj
        else:
            gt = obj
    work = replace(seq, imu=imu, poses=poses, ground_truth=gt)
    if imu is not None and len(imu) > 1:
        work = replace(work, imu=_fix_imu_units(work, imu, allowed, opts, changes))
        work = _fix_position_units(work, allowed, opts, changes)
    metadata = dict(seq.metadata)
    metadata["repairs"] = list(metadata.get("repairs") or []) + changes
    work = replace(work, metadata=metadata, findings=list(seq.findings))
    for c in changes:
        log.info("repair: %s", c)
    return work, changes


def _fix_rows(name: str, obj: Any, valid: np.ndarray, allowed: set[Repair], changes: list[str]) -> Any:
    """Drop non-finite rows, sort, drop repeated stamps (as allowed); says what it did in ``changes``."""
    n0 = len(obj)
    if Repair.DROP_NONFINITE in allowed and not valid.all():
        obj = obj.take(np.flatnonzero(valid))
        changes.append(f"{name}: dropped {n0 - len(obj)} rows with non-finite values or zero quaternions")
    t = obj.t_ns
    if Repair.SORT in allowed and len(t) > 1 and bool(np.any(t[1:] < t[:-1])):
        steps = int((t[1:] < t[:-1]).sum())
        obj = obj.take(np.argsort(t, kind="stable"))
        changes.append(f"{name}: sorted {len(t)} rows by time ({steps} backward steps)")
        t = obj.t_ns
    if Repair.DROP_DUPLICATES in allowed and len(t) > 1:
        if bool(np.all(t[1:] >= t[:-1])):
            keep = np.concatenate([[True], t[1:] != t[:-1]])
            idx = np.flatnonzero(keep)
        else:
            _, first = np.unique(t, return_index=True)
            idx = np.sort(first)
        if len(idx) < len(t):
            obj = obj.take(idx)
            changes.append(f"{name}: dropped {len(t) - len(idx)} rows with repeated stamps (kept the first)")
    return obj

def _fix_quat(name: str, obj: Any, allowed: set[Repair], opts: CheckOptions, changes: list[str]) -> Any:
    """Normalise quaternions and make them continuous (as allowed); says what it did in ``changes``."""
    q = obj.quat_wxyz
    if q is None or len(q) == 0:
        return obj
    if Repair.NORMALISE_QUATERNIONS in allowed:
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        dev = np.abs(norm[:, 0] - 1.0)
        n_off = int((dev > opts.quat_norm_tol).sum())
        max_dev = float(np.nanmax(dev)) if np.isfinite(dev).any() else 0.0
        if max_dev > 1e-12:  # leave already-unit quaternions bit-identical
            with np.errstate(divide="ignore", invalid="ignore"):
                q = q / norm
            obj = _replace_stream(obj, quat_wxyz=q)
            changes.append(f"{name}: normalised quaternions (max norm deviation {max_dev:.3g}; "
                           f"{n_off} rows beyond {opts.quat_norm_tol:g})")
    if Repair.CONTINUOUS_QUATERNIONS in allowed and len(q) > 1:
        dots = np.einsum("ij,ij->i", q[1:], q[:-1])
        flips = int((dots < 0).sum())
        if flips:
            sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
            obj = _replace_stream(obj, quat_wxyz=q * sign[:, None])
            changes.append(f"{name}: made quaternions continuous ({flips} sign flips)")
    return obj


def _fix_imu_units(work: Sequence, imu: ImuSeries, allowed: set[Repair], opts: CheckOptions, changes: list[str]
                   ) -> ImuSeries:
    """Scale the gyro from deg/s and the accelerometer from g where their checks fire (as allowed and
    not ignored); says what it did in ``changes``."""
    valid = finite_rows(imu.gyro_radps) & finite_rows(imu.acc_mps2)
    if Repair.GYRO_DEG_TO_RAD in allowed and "GYRO_DEGPS" not in opts.ignore:
        hit = detect_gyro_degps(work, valid)
        if hit is not None:
            imu = _replace_stream(imu, gyro_radps=imu.gyro_radps * DEG_TO_RAD)
            changes.append(f"imu: scaled gyro by pi/180 (deg/s to rad/s, rule {hit['rule']}; {len(imu)} rows)")
    if Repair.ACC_G_TO_MPS2 in allowed and "ACC_IN_G" not in opts.ignore:
        if detect_acc_in_g(masked_rows(imu.acc_mps2, valid)) is not None:
            imu = _replace_stream(imu, acc_mps2=imu.acc_mps2 * G_MPS2)
            changes.append(f"imu: scaled accelerometer by {G_MPS2} (g to m/s^2; {len(imu)} rows)")
    return imu


def _fix_stamp_unit(s: StreamView, other_t0_ns: list[int], allowed: set[Repair], opts: CheckOptions,
                    changes: list[str]) -> Any:
    """Stamps in s, ms or us scaled to ns where STAMP_UNIT fires (as allowed and not ignored)."""
    if Repair.STAMPS_TO_NS not in allowed or "STAMP_UNIT" in opts.ignore or len(s.t_ns) < 2:
        return s.obj
    found = stamp_unit(s.kind, time_stats(s.t_ns), other_t0_ns)
    if found is None:
        return s.obj
    unit, factor = found
    changes.append(f"{s.name}: stamps scaled from {unit} to nanoseconds (x{factor:.0e}; {len(s.t_ns)} rows)")
    return replace(s.obj, t_ns=scaled_stamps(s.obj.t_ns, factor))


def _fix_placeholders(name: str, obj: Any, allowed: set[Repair], opts: CheckOptions, changes: list[str]) -> Any:
    """Placeholder poses (origin, identity orientation) dropped (as allowed and not ignored)."""
    if Repair.DROP_PLACEHOLDER_POSES not in allowed or "POSE_PLACEHOLDERS" in opts.ignore:
        return obj
    from pipeline.checks.rig import placeholder_rows  # scipy: off the CLI start-up path

    poses = obj.to_pose_series() if hasattr(obj, "to_pose_series") else obj
    bad = placeholder_rows(poses)
    if not bad.any():
        return obj
    changes.append(f"{name}: dropped {int(bad.sum())} placeholder poses (origin with identity orientation)")
    return obj.take(np.flatnonzero(~bad))


def _fix_position_units(work: Sequence, allowed: set[Repair], opts: CheckOptions, changes: list[str]) -> Sequence:
    """Pose positions in mm or cm scaled to metres where POSITION_UNIT fires (as allowed and not ignored)."""
    if Repair.POSITIONS_TO_M not in allowed or "POSITION_UNIT" in opts.ignore:
        return work
    from pipeline.checks.rig import fit_rig  # scipy: off the CLI start-up path

    poses = dict(work.poses)
    for key, p in work.poses.items():
        fit = fit_rig(work.imu, p)
        factor = 1.0 if fit is None else fit.position_factor
        if factor != 1.0:
            poses[key] = replace(p, p_m=p.p_m * factor)
            changes.append(f"{pose_stream_label(key)}: positions scaled from {fit.scale.unit} to metres (x{factor:g}; "
                           f"{len(p)} rows)")
    return replace(work, poses=poses)
