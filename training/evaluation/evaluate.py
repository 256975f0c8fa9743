"""Evaluation of bias predictors on the test split (the paper's protocol, after AirIMU).

Protocol (AirIMU's ``evaluation/evaluate_state.py``: ``step_size = seqlen``, the integrator reset
to the ground-truth state of every segment):

* **Windows**: the test split made **non-overlapping**: per sequence, in time order, a window is
  kept when its first stamp is at or after the last stamp of the previously kept one.
* Each window is integrated from the reference state at its first sample with
  ``imu - bias_pred`` (:func:`validation.metrics.window_end_errors`, the project's one metric),
  under a stated gravity (:class:`training.config.EvalGravity`: ``nominal`` or ``recovered``; the
  summary's ``gravity_source`` names it per sequence).
* Per sequence: ``PRMSE = sqrt(mean_w |p_end - p_gt|^2)`` (m) and ``ROE = mean_w |Log(R_gt^T
  R_end)|`` (deg); the **Average** row is the mean over test sequences, as in Table I.
* A diffusion model draws ``K`` samples per window. Rows (:class:`~training.evaluation.outputs.Aggregation`): ``samples``
  (each metric per sample, averaged: the paper's figure), ``mean`` and ``median`` (the
  per-time-step mean / median of the K samples as one prediction). Deterministic predictors
  have one ``samples`` row.
* **Calibration** of a diffusion model's spread, per channel: the fraction of ground-truth bias
  values inside the central interval of the K samples, for :data:`CALIBRATION_LEVELS`.
* **Clip use** per sampler and channel (:class:`training.models.clip.ClipUse`).

Outputs (``OUT/``, written atomically): ``summary.json``,
``windows.parquet`` (one row per window, sampler, aggregation and sample), ``predictions.parquet``
(per time step and channel: the samples' mean and, for K > 1, std, median and quantiles) and
``examples.parquet`` (a few test windows, the same for every method, for the report's figure).
The records (:class:`~training.evaluation.outputs.EvaluationSummary`, :class:`~training.evaluation.outputs.EvaluationResult`
and their parts), their writer and their reader live in :mod:`training.evaluation.outputs`.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from pipeline.errors import ConfigError, InputFormatError
from training.config import Draw, EvaluationConfig, Sampler
from training.data.dataset import FORMAT_VERSION, STATE_BIAS
from training.evaluation.predictors import ModelPredictor, Predictor, ReferencePredictor, context_feeder
from training.evaluation.windows import TestWindows, load_test_windows
from training.fit.checkpoint import CheckpointError
from training.networks import get_network
from training.evaluation.outputs import (
    Aggregation,
    Calibration,
    EvaluationResult,
    EvaluationSummary,
    Metrics,
    RowResult,
    write_evaluation,
)
from training.evaluation.predictions import CHANNELS, prediction_frame
from training.references import get_reference
from validation.metrics import prmse_m, roe_deg, window_end_errors

log = logging.getLogger(__name__)

__all__ = [
    "CALIBRATION_LEVELS",
    "EvaluationConfig",
    "ModelPredictor",
    "ReferencePredictor",
    "TestWindows",
    "evaluate_predictor",
    "evaluate_reference",
    "evaluate_run",
    "load_test_windows",
]

#: Nominal central-interval levels of the calibration curve.
CALIBRATION_LEVELS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.68, 0.7, 0.8, 0.9, 0.95)
#: Quantiles of the samples kept per time step for the report's example windows.
EXAMPLE_QUANTILES = (0.025, 0.16, 0.5, 0.84, 0.975)
EXAMPLE_SAMPLES = 5  # individual prediction samples kept per example window (the paper's Fig. 3)
PROTOCOL = ("non-overlapping windows of the test split (every other 50%-overlap window), each integrated "
            "from the reference start state; end-point PRMSE (m) and ROE (deg) per sequence; Average = "
            "mean over sequences")


# ----------------------------------------------------------------------------- evaluation


@dataclass
class _Accumulator:
    """Per-window errors of one sampler, and the calibration counts."""

    pos: list[np.ndarray] = field(default_factory=list)  # [B, K] per batch, then mean/median [B]
    rot: list[np.ndarray] = field(default_factory=list)
    agg_pos: dict[Aggregation, list[np.ndarray]] = field(default_factory=dict)
    agg_rot: dict[Aggregation, list[np.ndarray]] = field(default_factory=dict)
    inside: np.ndarray = field(default_factory=lambda: np.zeros((len(CALIBRATION_LEVELS), 6)))
    count: int = 0


def _errors(items: dict[str, Any], bias: np.ndarray, gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """pos_err, rot_err [B, K] of predictions ``bias`` [B, K, T, 6]."""
    B, K, T, _ = bias.shape
    rep = lambda key: np.repeat(items[key].numpy(), K, axis=0)  # noqa: E731
    pos, rot = window_end_errors(rep("imu"), bias.reshape(B * K, T, 6), rep("dt_s"), rep("start_R"),
                                 rep("start_v"), rep("start_p"), rep("end_R"), rep("end_p"), gravity_mps2=gravity)
    return pos.reshape(B, K), rot.reshape(B, K)


def _coverage_counts(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """[levels, 6] counts of ground-truth values inside the central intervals of the samples."""
    levels = np.asarray(CALIBRATION_LEVELS)
    q = np.quantile(pred, np.concatenate([(1 - levels) / 2, (1 + levels) / 2]), axis=1)  # [2L, B, T, 6]
    lo, hi = q[:len(levels)], q[len(levels):]
    inside = (gt[None] >= lo) & (gt[None] <= hi)
    return inside.sum(axis=(1, 2))


def _batches(windows: TestWindows, size: int) -> Iterator[tuple[str, np.ndarray]]:
    for name in windows.sequences():
        rows = np.flatnonzero(windows.sequence == name)
        for i in range(0, len(rows), size):
            yield name, rows[i:i + size]


def _predicted_batches(predictor: Predictor, windows: TestWindows, draw: Draw,
                       size: int) -> Iterator[tuple[str, np.ndarray, dict[str, Any], np.ndarray]]:
    """``(sequence, rows, items, pred [B, K, T, 6])`` per evaluation batch of ``size`` windows. A stochastic
    predictor draws all of a sequence's windows in one call (it chunks them by ``draw.rows``; its samples
    do not depend on the batching), the others batch by batch."""
    for name in windows.sequences():
        every = np.flatnonzero(windows.sequence == name)
        whole = predictor.predict(windows.items(every), name, draw) if predictor.stochastic else None
        for i in range(0, len(every), size):
            rows = every[i:i + size]
            items = windows.items(rows)
            yield name, rows, items, (whole[i:i + size] if whole is not None else predictor.predict(items, name, draw))


def _example_rows(windows: TestWindows, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(len(windows), size=min(n, len(windows)), replace=False))


def _example_frame(pred: np.ndarray, items: dict[str, Any], rows: np.ndarray, sampler: Sampler | None,
                   windows: TestWindows) -> pd.DataFrame:
    """Long frame of example windows: per time step and channel, truth, the dataset's own bias (``dataset``,
    NaN without a ground-truth state), sample mean, quantiles and the first ``EXAMPLE_SAMPLES`` samples."""
    gt = items["bias"].numpy()
    t_s = np.concatenate([np.zeros((len(gt), 1)), np.cumsum(items["dt_s"].numpy(), axis=1)], axis=1)
    q = np.quantile(pred, EXAMPLE_QUANTILES, axis=1)  # [Q, B, T, 6]
    B, T, _ = gt.shape
    frame = {
        "window": np.repeat(rows, T * 6), "sequence": np.repeat(windows.sequence[rows], T * 6).astype(str),
        "t_s": np.repeat(t_s.reshape(-1), 6), "channel": np.tile(np.array(CHANNELS), B * T),
        "sampler": "" if sampler is None else sampler.value,
        "truth": gt.reshape(-1), "mean": pred.mean(axis=1).reshape(-1),
        "dataset": (items[STATE_BIAS].numpy().reshape(-1) if STATE_BIAS in items
                    else np.full(gt.size, np.nan)),
    }
    for j in range(min(EXAMPLE_SAMPLES, pred.shape[1]) if pred.shape[1] > 1 else 0):
        frame[f"sample{j}"] = pred[:, j].reshape(-1)
    for level, qq in zip(EXAMPLE_QUANTILES, q):
        frame[f"q{level:g}"] = qq.reshape(-1)
    return pd.DataFrame(frame)


def _run_draw(predictor: Predictor, windows: TestWindows, draw: Draw,
              config: EvaluationConfig) -> tuple[_Accumulator, pd.DataFrame, pd.DataFrame]:
    acc = _Accumulator()
    sampler, k = draw.sampler, draw.samples
    examples = _example_rows(windows, config.examples, config.seed)
    ex_frames, pred_frames = [], []
    aggs = (Aggregation.MEAN, Aggregation.MEDIAN) if k > 1 else ()
    from pipeline.progress import progress

    what = f"evaluate ({sampler.value}, {k} samples)" if sampler is not None else "evaluate"
    bar = progress(len(windows), desc=what, unit="window", logger=log)
    for name, rows, items, pred in _predicted_batches(predictor, windows, draw, config.batch_windows):
        g = windows.gravity_mps2[name]
        pos, rot = _errors(items, pred, g)
        pred_frames.append(prediction_frame(pred, rows, windows.sequence[rows], windows.t0_ns[rows],
                                            "" if sampler is None else sampler.value))
        acc.pos.append(pos)
        acc.rot.append(rot)
        for agg in aggs:
            point = pred.mean(axis=1) if agg is Aggregation.MEAN else np.median(pred, axis=1)
            p, r = _errors(items, point[:, None], g)
            acc.agg_pos.setdefault(agg, []).append(p[:, 0])
            acc.agg_rot.setdefault(agg, []).append(r[:, 0])
        if k > 1:
            acc.inside += _coverage_counts(pred, items["bias"].numpy())
            acc.count += pred.shape[0] * pred.shape[2]
        sel = np.isin(rows, examples)
        if sel.any():
            sub = {key: (v[sel] if torch.is_tensor(v) else v) for key, v in items.items()}
            ex_frames.append(_example_frame(pred[sel], sub, rows[sel], sampler, windows))
        bar.update(len(rows))
    bar.close()
    return (acc, pd.concat(ex_frames, ignore_index=True) if ex_frames else pd.DataFrame(),
            pd.concat(pred_frames, ignore_index=True))


def _metrics_samples(pos: np.ndarray, rot: np.ndarray) -> Metrics:
    """Per-sample PRMSE / ROE over windows [W, K], averaged over the K samples."""
    p = np.array([prmse_m(pos[:, j]) for j in range(pos.shape[1])])
    r = np.array([roe_deg(rot[:, j]) for j in range(rot.shape[1])])
    return Metrics(float(p.mean()), float(r.mean()), float(p.std()), float(r.std()), int(pos.shape[0]))


def _average(per_seq: Mapping[str, Metrics]) -> Metrics:
    vals = list(per_seq.values())
    return Metrics(float(np.mean([m.prmse_m for m in vals])), float(np.mean([m.roe_deg for m in vals])),
                   float(np.mean([m.prmse_std_m for m in vals])), float(np.mean([m.roe_std_deg for m in vals])),
                   int(sum(m.windows for m in vals)))


def _rows_of(acc: _Accumulator, windows: TestWindows, sampler: Sampler | None) -> list[RowResult]:
    order = np.concatenate([rows for _, rows in _batches(windows, 1 << 30)])
    seq = windows.sequence[order]
    names = windows.sequences()
    out = []
    pos, rot = np.concatenate(acc.pos), np.concatenate(acc.rot)
    per = {n: _metrics_samples(pos[seq == n], rot[seq == n]) for n in names}
    out.append(RowResult(sampler, Aggregation.SAMPLES, per, _average(per)))
    for agg in acc.agg_pos:
        p, r = np.concatenate(acc.agg_pos[agg]), np.concatenate(acc.agg_rot[agg])
        per = {n: _metrics_samples(p[seq == n][:, None], r[seq == n][:, None]) for n in names}
        out.append(RowResult(sampler, agg, per, _average(per)))
    return out


def _windows_frame(acc: _Accumulator, windows: TestWindows, sampler: Sampler | None) -> pd.DataFrame:
    order = np.concatenate([rows for _, rows in _batches(windows, 1 << 30)])
    pos, rot = np.concatenate(acc.pos), np.concatenate(acc.rot)
    W, K = pos.shape
    parts = [pd.DataFrame({
        "window": np.repeat(order, K), "sample": np.tile(np.arange(K), W), "aggregation": Aggregation.SAMPLES.value,
        "pos_err_m": pos.reshape(-1), "rot_err_deg": rot.reshape(-1)})]
    for agg in acc.agg_pos:
        parts.append(pd.DataFrame({"window": order, "sample": -1, "aggregation": agg.value,
                                   "pos_err_m": np.concatenate(acc.agg_pos[agg]),
                                   "rot_err_deg": np.concatenate(acc.agg_rot[agg])}))
    frame = pd.concat(parts, ignore_index=True)
    frame.insert(0, "sampler", "" if sampler is None else sampler.value)
    frame.insert(1, "sequence", windows.sequence[frame["window"].to_numpy()].astype(str))
    frame.insert(2, "t0_ns", windows.t0_ns[frame["window"].to_numpy()].astype(np.int64))
    return frame


def evaluate_predictor(predictor: Predictor, windows: TestWindows, config: EvaluationConfig = EvaluationConfig(),
                       *, kind: str, checkpoint: Mapping[str, Any] | None = None) -> EvaluationResult:
    """Evaluate one predictor on the test windows (see the module docstring).

    Args:
        predictor: A :class:`ReferencePredictor` or :class:`ModelPredictor`.
        windows: From :func:`load_test_windows`.
        config: Samples, samplers, seed.
        kind: "learned", "reference" or "oracle" (stored).
        checkpoint: Provenance of a learned model (stored).
    """
    t_start = time.perf_counter()
    draws = config.draws(predictor.stochastic)
    k = draws[0].samples
    rows, calib, clip, frames, examples, predictions = [], [], [], [], [], []
    for draw in draws:
        sampler = draw.sampler
        log.info("%s: sampling %d test windows, %d sample(s) each%s", predictor.name, len(windows.sequence), k,
                 f" ({sampler.value})" if sampler is not None else "")
        acc, ex, pr = _run_draw(predictor, windows, draw, config)
        predictions.append(pr)
        rows.extend(_rows_of(acc, windows, sampler))
        frames.append(_windows_frame(acc, windows, sampler))
        examples.append(ex)
        if acc.count:
            cov = acc.inside / acc.count
            calib.append(Calibration(sampler, CALIBRATION_LEVELS, tuple(tuple(map(float, c)) for c in cov)))
        use = predictor.clip_use(sampler) if hasattr(predictor, "clip_use") else None
        if use is not None:
            clip.append(use)
            log.info("%s %s: samples on the x0 clip per channel %s", predictor.name, sampler.value,
                     [f"{f:.2%}" for f in use.on_bound])
        for r in rows[-(3 if k > 1 else 1):]:
            log.info("%s %s: average PRMSE %.4f m, ROE %.4f deg", predictor.name, r.key or "samples",
                     r.average.prmse_m, r.average.roe_deg)
    m = windows.manifest
    summary = EvaluationSummary(
        method=predictor.name, label=predictor.label, kind=kind, samples=k, seed=config.seed,
        steps=config.steps if predictor.stochastic else None, windows=len(windows),
        windows_per_sequence={n: int(np.sum(windows.sequence == n)) for n in windows.sequences()},
        protocol=f"{PROTOCOL}; gravity: {config.gravity.value}; oracle random walk: {config.oracle_random_walk.value}",
        gravity_source=dict(windows.gravity_source), rows=tuple(rows), calibration=tuple(calib),
        clip=tuple(clip),
        checkpoint=dict(checkpoint or {}),
        dataset={"path": str(windows.root), "format_version": m.get("format_version"),
                 "config_hash": m.get("config_hash"), "rate_hz": m.get("rate_hz"),
                 "window_samples": m.get("window_samples"),
                 "label_pose_stream": {n: e.get("info", {}).get("label_pose_stream")
                                       for n, e in m.get("sequences", {}).items()},
                 "reference": {n: m["sequences"][n].get("info", {}).get("reference") for n in windows.sequences()},
                 "excluded": dict(m.get("excluded", {}))},
        seconds=time.perf_counter() - t_start,
    )
    return EvaluationResult(summary, pd.concat(frames, ignore_index=True), pd.concat(examples, ignore_index=True),
                            pd.concat(predictions, ignore_index=True))


# ----------------------------------------------------------------------------- entry points


def evaluate_reference(reference: str, dataset_dir: str | Path, out_dir: str | Path | None = None,
                       config: EvaluationConfig = EvaluationConfig()) -> EvaluationResult:
    """Evaluate a registered reference row (:mod:`training.references`); write it when ``out_dir`` is given.

    Raises:
        ConfigError: No row of that name.
    """
    row = get_reference(reference)
    windows = load_test_windows(dataset_dir, config, arrays=row.arrays)
    kind = "oracle" if row.oracle else "reference"
    result = evaluate_predictor(ReferencePredictor(row, windows), windows, config, kind=kind)
    if out_dir is not None:
        write_evaluation(result, out_dir)
    return result


def check_compatible(run: Any, windows: TestWindows, checkpoint: Path, *, method: str | None = None,
                     allow_train_overlap: bool = False) -> None:
    """Refuse a checkpoint that does not fit the evaluation dataset (one line naming file and fix).

    The IMU rate is compared before the window length (a window of another rate has another length too:
    the rate is what to fix). A test sequence the model trained or was validated on (the checkpoint's
    ``train_sequences`` / ``val_sequences``) is refused unless ``allow_train_overlap``.

    Raises:
        ConfigError: The checkpoint holds another method than ``method``; a test sequence the model saw.
        InputFormatError: Another dataset format version, IMU rate or window length.
    """
    checkpoint = Path(getattr(run, "path", checkpoint))  # the .pt file itself
    got = str(run.config.method)
    if method is not None and got != get_network(method).name:
        raise ConfigError(f"the checkpoint holds a {got} model, not {method}", path=checkpoint,
                          field="method", hint=f"give the run trained with --method {method}")
    trained = dict(run.dataset or {})
    m = windows.manifest
    if trained.get("format_version", FORMAT_VERSION) != FORMAT_VERSION:
        raise InputFormatError(f"the checkpoint was trained on dataset format {trained.get('format_version')}, "
                               f"this version reads {FORMAT_VERSION}", path=checkpoint,
                               hint="re-create the dataset with 'biasgt windows' and retrain")
    t_r, e_r = trained.get("rate_hz"), m.get("rate_hz")
    if t_r is not None and e_r is not None and abs(float(e_r) / float(t_r) - 1.0) > 0.01:
        raise InputFormatError(f"IMU rate {float(e_r):g} Hz, the checkpoint was trained at {float(t_r):g} Hz",
                               path=windows.root, hint=f"re-create the dataset with --resample-hz {float(t_r):g}")
    t_w, e_w = trained.get("window_samples"), m.get("window_samples")
    if t_w is not None and int(t_w) != int(e_w):
        rate = f" at {float(e_r):g} Hz" if e_r is not None else ""
        raise InputFormatError(f"windows of {e_w} samples{rate}, the checkpoint was trained on {t_w}",
                               path=windows.root, hint="cut the evaluation dataset with the training window_s "
                                                       "('biasgt windows --window-s') or retrain")
    if not allow_train_overlap:
        _refuse_seen_sequences(trained, windows, checkpoint)


def _refuse_seen_sequences(trained: dict[str, Any], windows: TestWindows, checkpoint: Path) -> None:
    """Refuse a test split holding a sequence the checkpoint's model trained or was validated on."""
    test = set(windows.dataset.sequences)
    for split in ("train", "val"):
        seen = sorted(test & set(trained.get(f"{split}_sequences") or ()))
        if seen:
            which = "trained" if split == "train" else "validated (chose its checkpoint)"
            raise ConfigError(f"the test split of {windows.root} holds {len(seen)} sequence(s) the model "
                              f"{which} on: {', '.join(seen)}", path=checkpoint,
                              hint="evaluate on a dataset whose test sequences the model never saw, or pass "
                                   "--allow-train-overlap to measure it anyway (not a test result)")


def _run_provenance(run: Any, checkpoint: Path) -> dict[str, Any]:
    from training.models.bias_model import count_parameters

    info = {"path": str(checkpoint), "method": str(run.config.method),
            "preset": getattr(run.config.preset, "value", run.config.preset), "seed": run.config.seed,
            "parameters": int(count_parameters(run.model))}
    meta = _read_json(Path(run.path).parent / "run.json")
    for key in ("steps", "best_step", "best_val_loss", "train_seconds", "windows_per_s"):
        if key in meta:
            info[key] = meta[key]
    return info


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def evaluate_run(checkpoint: str | Path, dataset_dir: str | Path, out_dir: str | Path | None = None,
                 config: EvaluationConfig = EvaluationConfig(), *, method: str | None = None,
                 device: str = "cpu", allow_train_overlap: bool = False) -> EvaluationResult:
    """Evaluate a trained run, rebuilt from its checkpoint alone (:func:`training.fit.checkpoint.load_run`).

    Args:
        checkpoint: A run folder (its ``best.pt``) or a ``.pt`` file.
        dataset_dir: Window dataset whose test split is evaluated.
        out_dir: Write the outputs here (atomically) when given.
        config: Samples, samplers, steps, seed.
        method: Expected method (the workflow's job), checked against the checkpoint.
        device: Torch device of the model.
        allow_train_overlap: Evaluate even when the test split holds sequences the model trained or
            was validated on (refused otherwise).

    Raises:
        CheckpointError / ConfigError / InputFormatError / DataError: see :func:`check_compatible`.
    """
    from training.fit.checkpoint import load_run

    checkpoint = Path(checkpoint)
    windows = load_test_windows(dataset_dir, config)
    run = load_run(checkpoint, device=device)
    check_compatible(run, windows, checkpoint, method=method, allow_train_overlap=allow_train_overlap)
    predictor = ModelPredictor(run, context=context_feeder(run, windows.root))
    try:
        result = evaluate_predictor(predictor, windows, config, kind="learned",
                                    checkpoint=_run_provenance(run, checkpoint))
    except np.linalg.LinAlgError as exc:  # finite but absurd predictions: the integrated attitude is not a rotation
        raise CheckpointError(f"the model's predicted bias cannot be integrated ({exc})", path=run.path,
                              hint="use another checkpoint, or train again with 'biasgt train' (the weights are "
                                   "damaged or the training diverged)") from None
    if out_dir is not None:
        write_evaluation(result, out_dir)
    return result
