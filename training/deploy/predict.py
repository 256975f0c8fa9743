"""Bias of a new recording from its IMU readings alone, with a trained model (``biasgt predict``).

The IMU stream (any input :func:`pipeline.io.load_sequence` reads, or a canonical store; no
poses needed) is cut into consecutive windows of the model's length ``T`` (samples ``0..T-1``,
``T..2T-1``, ...; the last window is aligned to the last sample, so it overlaps its
predecessor and only its new samples are kept). Each window is sampled ``K`` times; every IMU
sample gets the per-time-step sample mean (``bg_x ... ba_z``), standard deviation
(``bg_x_std ...``) and central 95 % interval (``bg_x_q025``, ``bg_x_q975``) of its window.
Regression / indirect models give ``K`` identical samples (std 0).

The table starts with the columns of the recovery's ``bias.csv`` (``t_ns``, bias, std), so it
is itself a bias file: ``biasgt validate --bias predicted.csv`` judges it like a recovered bias.
It is written as CSV and Parquet (same stem), atomically.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from pipeline.bias_table import BIAS_COLUMNS, STD_COLUMNS
from pipeline.files.atomic import OutputKind, atomic_path, check_output_location
from pipeline.errors import DataError
from pipeline.types import NS_PER_S, Sequence
from training.fit.checkpoint import check_finite_output
from training.config import SAMPLES, STEPS, Sampler
from training.networks import get_network

log = logging.getLogger(__name__)

__all__ = ["load_input", "predict_file", "predict_sequence", "window_starts"]

#: Relative difference allowed between the recording's IMU rate and the model's.
RATE_TOLERANCE = 0.01


def window_starts(n_samples: int, window: int) -> np.ndarray:
    """First sample of each window covering ``0..n_samples-1`` (the last aligned to the end)."""
    if n_samples < window:
        return np.zeros(0, dtype=np.int64)
    starts = np.arange(0, n_samples - window + 1, window)
    if starts[-1] + window < n_samples:
        starts = np.append(starts, n_samples - window)
    return starts.astype(np.int64)


def load_input(path: str | Path, reader_kwargs: Mapping[str, Any] | None = None, *,
               repairs: Iterable[Any] = (), check_options: Any = None) -> Sequence:
    """A canonical store, or any input the readers load, checked as every reader command checks it.

    Raises:
        FatalCheckError: Wrong units (acc in g, gyro in deg/s), unsorted stamps, ... as
            ``biasgt recover`` refuses them (:func:`pipeline.ingest.load_checked`).
    """
    from pipeline.ingest import load_checked

    return load_checked(path, reader_kwargs, repairs=repairs, check_options=check_options, action="predict")


def predict_batch(imu: np.ndarray, temperature: np.ndarray | None, dtype: torch.dtype):
    """A WindowBatch of IMU windows [B, T, 6]; the reference fields, which sampling never reads, are zero."""
    from training.data.batch import TEMPERATURE_KEY, WindowBatch

    B, T, _ = imu.shape
    z = lambda *shape: torch.zeros(*shape, dtype=dtype)  # noqa: E731
    items = {"imu": torch.as_tensor(imu, dtype=dtype), "bias": z(B, T, 6), "bias_std": z(B, T, 6),
             "dt_s": z(B, T - 1), "start_R": z(B, 3, 3), "start_v": z(B, 3), "start_p": z(B, 3),
             "end_R": z(B, 3, 3), "end_v": z(B, 3), "end_p": z(B, 3)}
    if temperature is not None:
        items[TEMPERATURE_KEY] = torch.as_tensor(temperature, dtype=dtype)
    return WindowBatch.from_items(items)


def predict_sequence(run, sequence: Sequence, *, samples: int = SAMPLES, sampler: Sampler = Sampler.DDIM,
                     steps: int = STEPS, seed: int = 0, batch_windows: int = 32) -> pd.DataFrame:
    """Per-IMU-sample predicted bias of ``sequence`` (see the module docstring).

    Args:
        run: A :class:`training.fit.checkpoint.LoadedRun`.
        sequence: The recording (its IMU, and temperature when the model uses it).

    Raises:
        DataError: No IMU, shorter than one window, or an IMU rate other than the model's.
        CheckpointError: The model predicts a non-finite bias.
    """
    imu = sequence.imu
    T = int(run.dataset["window_samples"])
    if imu is None or len(imu) < T:
        raise DataError(f"'{sequence.name}' has {0 if imu is None else len(imu)} IMU samples, fewer than one "
                        f"window of {T}", hint="give a longer recording")
    rate = NS_PER_S / float(np.median(np.diff(imu.t_ns)))
    model_rate = run.dataset.get("rate_hz")
    if model_rate and abs(rate / float(model_rate) - 1.0) > RATE_TOLERANCE:
        raise DataError(f"'{sequence.name}' has IMU rate {rate:.4g} Hz, the model was trained at {float(model_rate):g} Hz",
                        hint=f"resample it to the model's rate: biasgt predict ... --resample-hz {float(model_rate):g}, "
                             f"or use a model trained on windows at {rate:.4g} Hz")
    method = get_network(run.config.method)
    k = samples if method.is_diffusion else 1
    starts = window_starts(len(imu), T)
    idx = starts[:, None] + np.arange(T)[None, :]
    imu6 = imu.imu_6
    temp = imu.temperature_degc
    model = run.model
    dtype = next(model.parameters()).dtype
    device = next(model.parameters()).device
    gen = torch.Generator(device=device).manual_seed(seed)
    kwargs = {"sampler": sampler, "steps": steps} if method.is_diffusion else {}
    log.info("sampling '%s': %d windows of %d samples, %d sample(s) each", sequence.name, len(starts), T, k)
    mean = np.empty((len(starts), T, 6))
    std, q_lo, q_hi = np.empty_like(mean), np.empty_like(mean), np.empty_like(mean)
    from pipeline.progress import progress

    bar = progress(len(starts), desc=f"predict {sequence.name} ({k} sample{'s' * (k > 1)})", unit="window",
                   logger=log)
    for b in range(0, len(starts), batch_windows):
        sl = idx[b:b + batch_windows]
        batch = predict_batch(imu6[sl], None if temp is None else temp[sl], dtype).to(device)
        pred = model.sample(batch, num_samples=k, generator=gen, **kwargs).to("cpu", torch.float64).numpy()  # [B, K, T, 6]
        check_finite_output(pred, run.path)
        mean[b:b + len(sl)] = pred.mean(axis=1)
        std[b:b + len(sl)] = pred.std(axis=1)
        q_lo[b:b + len(sl)], q_hi[b:b + len(sl)] = np.quantile(pred, (0.025, 0.975), axis=1)
        bar.update(len(sl))
    bar.close()
    owner = np.full(len(imu), -1)
    for w, s in enumerate(starts):  # each sample from the first window covering it
        seg = slice(s, s + T)
        owner[seg] = np.where(owner[seg] < 0, w, owner[seg])
    pos = np.arange(len(imu)) - starts[owner]
    frame = pd.DataFrame({"t_ns": imu.t_ns})
    for arr, suffix in ((mean, ""), (std, "_std")):
        for i, c in enumerate(BIAS_COLUMNS):
            frame[c + suffix] = arr[owner, pos, i]
    assert list(frame.columns[7:]) == list(STD_COLUMNS)
    frame["window"] = owner
    for arr, suffix in ((q_lo, "_q025"), (q_hi, "_q975")):
        for i, c in enumerate(BIAS_COLUMNS):
            frame[c + suffix] = arr[owner, pos, i]
    log.info("predicted the bias of '%s': %d windows of %d samples, %d sample(s) each", sequence.name, len(starts),
             T, k)
    return frame


def predict_file(checkpoint: str | Path, input_path: str | Path, out_path: str | Path, *, samples: int = SAMPLES,
                 sampler: Sampler = Sampler.DDIM, steps: int = STEPS, seed: int = 0, device: str = "cpu",
                 reader_kwargs: Mapping[str, Any] | None = None, repairs: Iterable[Any] = (),
                 check_options: Any = None, resample_hz: float | None = None) -> list[Path]:
    """Predict the bias of a recording and write ``OUT.csv`` and ``OUT.parquet`` (atomically each).

    Args:
        reader_kwargs / repairs / check_options: How the input is read and checked
            (:func:`load_input`).
        resample_hz: Resample the IMU to this rate first, anti-alias filtered
            (:func:`pipeline.resample.resample_imu_filtered`); the output is at the resampled stamps.

    Returns:
        The two files written.
    """
    from training.fit.checkpoint import load_run

    out = Path(out_path)
    paths = [out.with_suffix(".csv"), out.with_suffix(".parquet")]
    for path in paths:  # before any work
        check_output_location(path, OutputKind.FILE)
    run = load_run(checkpoint, device=device)
    sequence = load_input(input_path, reader_kwargs, repairs=repairs, check_options=check_options)
    if resample_hz is not None and sequence.imu is not None:
        from dataclasses import replace

        from pipeline.resample import resample_imu_filtered

        sequence = replace(sequence, imu=resample_imu_filtered(sequence.imu, resample_hz))
    frame = predict_sequence(run, sequence, samples=samples, sampler=Sampler(sampler), steps=steps, seed=seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(paths[0]) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.9g")
    with atomic_path(paths[1]) as tmp:
        frame.to_parquet(tmp, index=False)
    return paths
