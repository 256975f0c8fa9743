"""Bias sources of a validation: the dataset's own bias, a recovery's, bias files, zero and a constant.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from interpolation.bias import interpolate_bias
from pipeline.bias_table import BiasTrack, read_bias_csv
from pipeline.errors import DataError, InputFormatError, ValidationError
from pipeline.io.asl import read_asl_state_csv
from pipeline.types import (Sequence,
                            StateSeries)
from recovery.outputs import RecoveryOutputs
from validation.config import BiasSourceKind  # defined with the options: light for the CLI's help
from validation.reference import check_increasing

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- recovery output and bias files


def _header_line(path: Path) -> str:
    try:
        with path.open("r", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.strip():
                    return line
    except OSError as exc:
        raise InputFormatError(f"cannot read bias file ({exc.strerror})", path=path) from None
    return ""


def read_bias_file(path: str | Path) -> BiasTrack:
    """Read any bias file biasgt knows, as a :class:`BiasTrack` (not yet at IMU rate).

    Accepted: the recovery contract ``bias.csv`` (``t_ns,bg_x,...,ba_z_std``; the ``*_std``
    columns optional, 0 when absent) or an interpolated bias table (``.csv``/``.parquet``, same
    columns); a EuRoC/OpenVINS state CSV
    (``#time(ns),px,py,pz,qw,qx,qy,qz,vx,vy,vz,bwx,bwy,bwz,bax,bay,baz`` or EuRoC's
    ``state_groundtruth_estimate0/data.csv``), whose bias columns are used (std = 0).

    Raises:
        InputFormatError: Missing file or an unknown layout.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("bias file does not exist", path=path, hint="check the path")
    if path.suffix == ".parquet" or "bg_x" in _header_line(path):
        return read_bias_csv(path, require_std=False)
    try:
        state, _ = read_asl_state_csv(path, stream="bias")
    except InputFormatError as exc:
        raise InputFormatError(
            f"not a bias file ({exc.problem})", path=path,
            hint="give a bias.csv (t_ns,bg_x,...,ba_z_std), a bias .parquet, or a EuRoC/OpenVINS state CSV",
        ) from None
    return _state_bias_track(state, path)


def _state_bias_track(state: StateSeries, path: Path | None = None) -> BiasTrack:
    order = np.argsort(state.t_ns, kind="stable")
    t = state.t_ns[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    bias = np.hstack([state.bias_gyro_radps, state.bias_acc_mps2])[order][keep]
    if not np.all(np.isfinite(bias)):
        raise DataError("bias columns hold NaN or inf values", path=path, hint="clean the bias file")
    return BiasTrack(t[keep], bias, np.zeros_like(bias))


def dataset_bias(sequence: Sequence) -> BiasTrack | None:
    """The sequence's own ground-truth bias (EuRoC ``b_w``, ``b_a``), or None."""
    if sequence.ground_truth is None or len(sequence.ground_truth) == 0:
        return None
    return _state_bias_track(sequence.ground_truth)


def recovered_bias_at_imu(keyframes: BiasTrack, imu_t_ns: np.ndarray, random_walk: np.ndarray | None) -> BiasTrack:
    """The recovery's keyframe bias at the IMU stamps (:func:`interpolate_bias`, LINEAR).

    Stamps outside the recovered span are held and flagged ``clamped`` (validation drops them).
    """
    rw = np.zeros(6) if random_walk is None else np.asarray(random_walk, dtype=float)
    return interpolate_bias(keyframes, imu_t_ns, random_walk=rw, clamp=True)


@dataclass(frozen=True)
class BiasSource:
    """A named bias trajectory and its role.

    Attributes:
        name / kind / track: The source.
        gravity_mps2: The gravity, in the reference's world frame, that this bias was estimated
            against and is integrated with, [3]; None: the reference's own gravity.
    """

    name: str
    kind: BiasSourceKind
    track: BiasTrack
    gravity_mps2: np.ndarray | None = None


def infer_kind(name: str) -> BiasSourceKind:
    try:
        return BiasSourceKind(name.lower())
    except ValueError:
        return BiasSourceKind.FILE


def std_at(track: BiasTrack, t_ns: np.ndarray) -> np.ndarray:
    """The track's sigma at ``t_ns`` [N, 6] (linear, ends held; zeros for a track without sigma)."""
    std = np.asarray(track.std, dtype=np.float64)
    if not np.any(std):
        return np.zeros((len(t_ns), 6))
    t = np.asarray(track.t_ns, dtype=np.float64)
    return np.stack([np.interp(np.asarray(t_ns, dtype=np.float64), t, std[:, c]) for c in range(6)], axis=1)


def bias_at(track: BiasTrack, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bias [N, 6], covered [N]) of a track at the IMU stamps (linear; never extrapolated)."""
    if len(track.t_ns) == len(t_ns) and np.array_equal(track.t_ns, t_ns):
        covered = np.ones(len(t_ns), bool) if track.clamped is None else ~np.asarray(track.clamped, bool)
        return np.asarray(track.bias, dtype=np.float64), covered
    t = np.asarray(track.t_ns, dtype=np.int64)
    if len(t) == 1:  # a constant bias covers everything
        return np.repeat(np.asarray(track.bias, dtype=np.float64), len(t_ns), axis=0), np.ones(len(t_ns), bool)
    check_increasing(t, "bias")
    at = interpolate_bias(track, t_ns, random_walk=np.zeros(6), clamp=True)
    covered = ~at.clamped
    if track.clamped is not None and np.any(track.clamped):  # rows held by an earlier interpolation
        held = np.asarray(track.clamped, bool)
        inner = t[~held]
        covered &= (t_ns >= inner[0]) & (t_ns <= inner[-1]) if len(inner) else False
    return at.bias, covered


# ----------------------------------------------------------------------------- assembling the inputs (CLI, workflow)


def bias_sources(
    sequence: Sequence,
    *,
    recovery: RecoveryOutputs | None = None,
    bias_files: Sequence_[tuple[str | None, str | Path]] = (),
) -> dict[str, BiasSource]:
    """The bias sources of a validation: the recovery's bias and any bias files.

    The recovery's ``bias.csv`` becomes ``"recovered"`` (RECOVERED, interpolated to the IMU stamps
    with the recovery's random walks, else the calibration's). An unnamed file is the bias under
    test (``"recovered"``) when it is the first one and no recovery is given, else FILE named by
    its stem; a named one is FILE.

    Args:
        sequence: The sequence (its IMU stamps and calibration are used).
        recovery: The recovery folder (:meth:`recovery.outputs.RecoveryOutputs.read`), or None.
        bias_files: ``(name or None, path)`` pairs.

    Raises:
        ValidationError: Nothing to validate, or a name used twice or reserved.
        InputFormatError: An unreadable bias file.
    """
    if not bias_files and recovery is None:
        raise ValidationError("nothing to validate", field="--bias", hint="give --recovery DIR or --bias FILE")
    if sequence.imu is None:
        raise ValidationError(f"sequence '{sequence.name}' has no IMU to integrate",
                              hint="give an input with IMU readings")
    cal = sequence.calibration
    rw_cal = np.array([cal.gyro_random_walk] * 3 + [cal.acc_random_walk] * 3, dtype=float)
    sources: dict[str, BiasSource] = {}
    if recovery is not None:
        rw = recovery.report.random_walk if recovery.report.random_walk is not None else rw_cal
        track = recovered_bias_at_imu(recovery.bias, sequence.imu.t_ns, rw)
        sources["recovered"] = BiasSource("recovered", BiasSourceKind.RECOVERED, track)
    unnamed = 0
    for name, path in bias_files:
        path = Path(path)
        track = read_bias_file(path)
        if name is None:
            unnamed += 1
            first = unnamed == 1 and recovery is None
            name = "recovered" if first else path.stem
            kind = BiasSourceKind.RECOVERED if first else BiasSourceKind.FILE
        else:
            kind = BiasSourceKind.FILE
        if name in sources or name in ("zero", "constant"):
            raise ValidationError(f"bias source name '{name}' is used twice or reserved", field="--bias",
                                  hint="name the sources with --bias NAME=FILE (zero and constant are reserved)")
        sources[name] = BiasSource(name, kind, track)
    return sources
