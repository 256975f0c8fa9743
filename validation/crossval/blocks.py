"""Cross-validation of a recovered bias by time blocks: recover on some blocks, judge on the others.

The 1-s integration check of :mod:`validation.validate` against the very poses a bias was fitted to
cannot see what the bias absorbed from them (a tilt of the pose frame, pose artefacts). Here the
recording is cut into blocks of ``block_s`` from the first IMU stamp; block ``b`` belongs to fold
``b % n_folds``. For fold ``k`` the pose samples inside fold ``k``'s blocks are removed, the bias is
recovered from the rest, and that recovery's bias (and, when estimated, its IMU intrinsics) is used
in fold ``k``'s blocks only. Every IMU sample's bias then comes from a recovery that never saw the
poses around it. The windows judged are those wholly inside one block (no window mixes two
recoveries), integrated against the FULL pose stream with the project's one metric
(:mod:`validation.crossval.heldout`: :func:`validation.metrics.window_errors`, PRMSE, ROE).

A recovery sees a held-out block as a pose gap, spanned by keyframes without pose factors
(:mod:`recovery.solver.gaps`): the block's own IMU readings still enter, its poses do not. A held-out block
at the start or end of the recording lies outside the fold recovery's keyframe span (poses on one
side only): there the prediction of the bias random walk from the nearest keyframe is that keyframe's
value with a sigma growing as ``sigma_end^2 + q |t - t_end|`` (:func:`fold_prediction`), so that a
held-out bias far from any pose it was fitted to is judged at its real uncertainty.

A fold whose recovery fails (too few poses left, too little motion, a degenerate optimisation) is
dropped and counted: its blocks have no held-out bias, and the other folds still judge theirs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from interpolation.bias import interpolate_bias
from pipeline.bias_table import BiasTrack
from pipeline.errors import BiasgtError, ValidationError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, Sequence

__all__ = ["BlockFolds", "CrossValidatedBias", "crossvalidate_recovery", "fold_prediction", "held_constant",
           "heldout_track", "imu_and_bias_of", "without_fold"]


@dataclass(frozen=True)
class BlockFolds:
    """Blocks of ``block_s`` from ``t0_ns``; block ``b`` is in fold ``b % n_folds``."""

    t0_ns: int
    block_s: float
    n_folds: int

    def __post_init__(self) -> None:
        if not self.block_s > 0 or self.n_folds < 2:
            raise ValidationError(f"cross-validation needs block_s > 0 and n_folds >= 2, got {self.block_s!r} and "
                                  f"{self.n_folds!r}", field="block_s", hint="e.g. block_s 10, n_folds 3")

    def block(self, t_ns: np.ndarray) -> np.ndarray:
        """Block index of each stamp, int [N] (negative before ``t0_ns``)."""
        return np.floor((np.asarray(t_ns, dtype=np.int64) - self.t0_ns) / (self.block_s * NS_PER_S)).astype(np.int64)

    def fold(self, t_ns: np.ndarray) -> np.ndarray:
        """Fold of each stamp, int [N] in ``[0, n_folds)``."""
        return np.mod(self.block(t_ns), self.n_folds)


def without_fold(poses: PoseSeries, folds: BlockFolds, k: int, time_offset_s: float = 0.0) -> PoseSeries:
    """The pose stream without its samples in fold ``k`` (stamps moved by ``time_offset_s`` to the IMU clock
    to decide the fold)."""
    return poses.take(folds.fold(poses.t_ns + int(round(time_offset_s * NS_PER_S))) != k)


def imu_and_bias_of(imu: ImuSeries, result) -> tuple[ImuSeries, np.ndarray]:
    """The readings to integrate and the bias to subtract, [N, 6], for a recovery result.

    A recovery with IMU intrinsics (``report["intrinsics"]``) reports the bias in the raw readings'
    convention ``b = M b'``; its readings are corrected (:meth:`recovery.intrinsics.estimate.ImuIntrinsics.correct`)
    and its bias taken as ``b' = M^-1 b``. Otherwise the raw readings and the bias as recovered.
    """
    bias = result.bias_at(imu.t_ns)
    rep = result.report.get("intrinsics")
    if not rep:
        return imu, bias
    from recovery.intrinsics.estimate import ImuIntrinsics

    intr = ImuIntrinsics(np.array(rep["gyro_matrix"]), np.array(rep["acc_matrix"]),
                         np.array(rep["gyro_g_sensitivity"]))
    corrected = intr.correct(imu, bias[:, 3:])
    b = np.hstack([np.linalg.solve(intr.gyro_matrix, bias[:, :3].T).T,
                   np.linalg.solve(intr.acc_matrix, bias[:, 3:].T).T])
    return corrected, b


def fold_prediction(result, t_ns: np.ndarray) -> BiasTrack:
    """A fold recovery's bias and sigma at ``t_ns`` (raw readings' convention), [M, 6] each.

    Inside the recovery's keyframe span: its bias and sigma interpolated. Beyond it (a held-out block at
    the recording's start or end): the random walk's prediction from the end keyframe, its value with the
    variance ``sigma_end^2 + q |t - t_end|`` (:func:`interpolation.bias.interpolate_bias` with ``clamp``;
    ``q`` the squared random walk the recovery used, ``report["noise"]``; flagged ``clamped``). A result
    without keyframes or random walks gives its own ``bias_at`` / ``std_at``.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    noise = (getattr(result, "report", None) or {}).get("noise") or {}
    g_rw, a_rw = noise.get("gyro_random_walk"), noise.get("acc_random_walk")
    if g_rw is None or a_rw is None or getattr(result, "t_ns", None) is None:
        return BiasTrack(t_ns, result.bias_at(t_ns), result.std_at(t_ns))
    keyframes = BiasTrack(np.asarray(result.t_ns, dtype=np.int64),
                          np.hstack([result.bias_gyro_radps, result.bias_acc_mps2]).astype(float),
                          np.hstack([result.bias_gyro_std_radps, result.bias_acc_std_mps2]).astype(float))
    return interpolate_bias(keyframes, t_ns, random_walk=np.array([float(g_rw)] * 3 + [float(a_rw)] * 3),
                            clamp=True)


@dataclass(frozen=True)
class CrossValidatedBias:
    """A bias at the IMU stamps where each sample's value comes from the fold that left it out.

    Attributes:
        imu: Readings to integrate (corrected per fold when the recovery estimated intrinsics).
        bias: Bias at the IMU stamps, [N, 6] (gyro rad/s, acc m/s^2), in the convention of ``imu``.
        recoveries: Each fold's recovery result, in fold order (None for a dropped fold).
        raw_bias: The bias as the recoveries report it (raw readings' convention), [N, 6]; None when
            not spliced from recoveries. NaN in a dropped fold's blocks.
        dropped: ``{fold: reason}`` of the folds whose recovery failed.
        raw_std: The bias sigma of the fold that left each sample out, [N, 6] (raw readings' convention;
            NaN in a dropped fold's blocks; growing with the random walk beyond the fold's span,
            :func:`fold_prediction`), or None.
    """

    imu: ImuSeries
    bias: np.ndarray
    recoveries: tuple
    raw_bias: np.ndarray | None = None
    dropped: dict[int, str] = dataclasses.field(default_factory=dict)
    raw_std: np.ndarray | None = None


def crossvalidate_recovery(sequence: Sequence, stream: str, folds: BlockFolds,
                           recover_fn: Callable[[Sequence, str], object]) -> CrossValidatedBias:
    """Recover once per fold without that fold's poses and splice the held-out biases.

    Args:
        sequence: IMU + pose streams.
        stream: The pose stream recovered from.
        folds: The blocks and folds.
        recover_fn: ``(sequence, stream) -> RecoveryResult`` (e.g. ``recovery.recover.recover`` with a config).

    Returns:
        The spliced bias (and readings) at the IMU stamps, the per-fold recoveries, and the folds
        dropped because their recovery failed (a :class:`pipeline.errors.BiasgtError`).
    """
    imu = sequence.imu
    fold_of_imu = folds.fold(imu.t_ns)
    gyro, acc = imu.gyro_radps.copy(), imu.acc_mps2.copy()
    bias, raw, raw_std = (np.full((len(imu), 6), np.nan) for _ in range(3))
    results: list = []
    dropped: dict[int, str] = {}
    for k in range(folds.n_folds):
        poses = sequence.poses[stream]
        seq_k = dataclasses.replace(sequence, poses={**sequence.poses, stream: without_fold(poses, folds, k)})
        try:
            res = recover_fn(seq_k, stream)
        except BiasgtError as exc:
            dropped[k] = str(exc)
            results.append(None)
            continue
        results.append(res)
        imu_k, bias_k = imu_and_bias_of(imu, res)
        m = fold_of_imu == k
        gyro[m], acc[m], bias[m] = imu_k.gyro_radps[m], imu_k.acc_mps2[m], bias_k[m]
        predicted = fold_prediction(res, imu.t_ns[m])
        raw[m], raw_std[m] = predicted.bias, predicted.std
    return CrossValidatedBias(dataclasses.replace(imu, gyro_radps=gyro, acc_mps2=acc), bias, tuple(results), raw,
                              dropped, raw_std)


def held_constant(cv: CrossValidatedBias, imu: ImuSeries, folds: BlockFolds) -> CrossValidatedBias:
    """The cross-validated bias held constant per fold: in fold ``k``'s blocks, the mean of fold ``k``'s recovery
    over the samples it was fitted on (the cross-validated counterpart of a sequence-constant bias estimate)."""
    fold_of_imu = folds.fold(imu.t_ns)
    bias = np.full_like(cv.bias, np.nan)
    for k, res in enumerate(cv.recoveries):
        if res is None:
            continue
        m = fold_of_imu == k
        bias[m] = imu_and_bias_of(imu, res)[1][~m].mean(axis=0)
    return CrossValidatedBias(cv.imu, bias, cv.recoveries, dropped=dict(cv.dropped))


def heldout_track(sequence: Sequence, stream: str, recovery_options: dict, folds: BlockFolds
                  ) -> tuple[BiasTrack, dict[int, str]]:
    """The recovered bias cross-validated by blocks, at the IMU stamps (raw readings' convention, with the
    sigma of the fold that left each sample out; NaN in a dropped fold's blocks), and the dropped folds
    ``{fold: reason}``.

    Args:
        sequence: IMU + pose streams.
        stream: The pose stream the recovery fitted.
        recovery_options: The recovery's options (``recovery.json`` ``config``), used for every fold.
        folds: The blocks and folds.
    """
    from recovery.config import RecoveryConfig
    from recovery.recover import recover

    config = RecoveryConfig.from_dict(recovery_options)
    cv = crossvalidate_recovery(sequence, stream, folds, lambda s, st: recover(s, pose_stream=st, config=config))
    return BiasTrack(sequence.imu.t_ns, cv.raw_bias, cv.raw_std), dict(cv.dropped)
