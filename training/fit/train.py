"""Train one bias model on a window dataset: resumable, deterministic, validation-selected.

``train(config, dataset_dir, out_dir)`` reads the dataset's train and validation splits (never the
test split), builds the model with the manifest's normaliser statistics, and runs AdamW with a
linear warm-up + cosine learning-rate schedule, gradient-norm clipping and, for diffusion models,
an EMA of the weights (validation and evaluation use the EMA weights). Run layout and checkpoint
contents: :mod:`training.fit.checkpoint`.

Determinism: weights are initialised from ``seed``; the batch order is a pure function of
``(seed, step)`` (:class:`BatchOrder`: one permutation per epoch, drawn from a generator seeded
with ``seed`` and the epoch); diffusion noise and steps come from a generator whose state is
checkpointed with the torch, numpy and python RNG states (dropout uses torch's global RNG, which
nothing else draws from: the data loaders have generators of their own). So a run resumed
from ``last.pt`` repeats exactly the steps of an uninterrupted run, and the same seed on the same
data gives the same weights (on one device type and thread count).

Data-parallel: under ``torchrun`` (``WORLD_SIZE`` > 1) each process takes its share of every
global batch (:class:`BatchOrder` shards it), gradients are averaged by
``DistributedDataParallel`` (gloo on CPU, nccl on CUDA), and rank 0 alone validates and writes.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import os
import random
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, default_collate

from pipeline.files.atomic import write_text_atomic
from pipeline.errors import BiasgtError, DataError
from training.data.batch import TEMPERATURE_KEY, WindowBatch
from training.models.clip import clip_bounds
from training.fit.checkpoint import BEST, CHECKPOINT_FORMAT, LAST, METRICS, RUN_JSON, load_checkpoint, save_checkpoint
from training.config import ModelConfig, TrainConfig
from training.data.dataset import MANIFEST, Split, WindowDataset
from training.fit.ema import EMA
from training.fit.run_folder import hold_run_folder
from training.models.bias_model import BiasModel, build_model, count_parameters
from training.data.normalizer import Normalizer

log = logging.getLogger(__name__)

__all__ = ["TrainingError", "BatchOrder", "train", "METRIC_COLUMNS"]

METRIC_COLUMNS = ("step", "train_loss", "val_loss", "lr", "seconds")
#: Options that may differ between a run and its resumption (they do not change the result).
_RESUMABLE_CHANGES = ("max_steps", "device", "num_workers", "threads")


class TrainingError(BiasgtError):
    """Training cannot start or cannot go on."""


class BatchOrder:
    """Which dataset items make up the global batch of each step, and this process's share.

    Epoch ``e`` is ``torch.randperm(n)`` from a generator seeded with ``seed * 1_000_003 + e``;
    step ``s`` (from 0) takes the ``s % per_epoch``-th run of ``batch_size`` items of epoch
    ``s // per_epoch`` (the incomplete tail of an epoch is dropped when ``n >= batch_size``). Rank
    ``r`` of ``world`` processes takes items ``r, r + world, ...`` of each global batch.
    """

    def __init__(self, n: int, batch_size: int, seed: int, rank: int = 0, world: int = 1) -> None:
        self.n, self.seed, self.rank, self.world = n, seed, rank, world
        self.batch_size = min(batch_size, n)
        self.per_epoch = n // self.batch_size
        self._epoch, self._perm = -1, torch.empty(0, dtype=torch.int64)

    def global_batch(self, step: int) -> list[int]:
        epoch, k = divmod(step, self.per_epoch)
        if epoch != self._epoch:
            g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
            self._epoch, self._perm = epoch, torch.randperm(self.n, generator=g)
        return self._perm[k * self.batch_size:(k + 1) * self.batch_size].tolist()

    def local_batch(self, step: int) -> list[int]:
        return self.global_batch(step)[self.rank::self.world]


class _StepBatches(torch.utils.data.Sampler):
    """Batch sampler yielding this process's batch for steps ``start .. stop - 1``."""

    def __init__(self, order: BatchOrder, start: int, stop: int) -> None:
        self.order, self.start, self.stop = order, start, stop

    def __len__(self) -> int:
        return max(0, self.stop - self.start)

    def __iter__(self):
        for step in range(self.start, self.stop):
            yield self.order.local_batch(step)


@dataclass
class _Data:
    train: WindowDataset
    val: WindowDataset
    manifest: dict[str, Any]
    info: dict[str, Any]
    normalizer: Normalizer
    gravity: dict[str, list[float]] = field(default_factory=dict)
    context: Any = None  # a context network's training.context.model.ContextFeeder, else None

    def collate(self, items: list[dict[str, Any]]) -> WindowBatch:
        out = default_collate(items)
        if self.context is not None:
            out["context"] = self.context(out["sequence"], out["t0_ns"], out["imu"].shape[1]).to(out["imu"].dtype)
        if self.gravity:
            from training.models.bias_model import DEFAULT_GRAVITY_MPS2

            out["gravity_mps2"] = torch.tensor([self.gravity.get(n, DEFAULT_GRAVITY_MPS2) for n in out["sequence"]],
                                               dtype=out["imu"].dtype)
        return WindowBatch.from_items(out)


def _temperature_stats(ds: WindowDataset) -> tuple[float, float]:
    """Mean and std (deg C) of the train split's temperature samples."""
    s = s2 = n = 0.0
    for items in DataLoader(ds, batch_size=1024):
        t = items[TEMPERATURE_KEY].double()
        s, s2, n = s + float(t.sum()), s2 + float((t * t).sum()), n + t.numel()
    mean = s / n
    return mean, math.sqrt(max(s2 / n - mean * mean, 0.0))


def _open_data(config: TrainConfig, dataset_dir: Path) -> _Data:
    """Open the train and validation splits and check them (one-line errors, nothing written)."""
    train_ds = WindowDataset(dataset_dir, Split.TRAIN)
    manifest = train_ds.manifest
    mpath = dataset_dir / MANIFEST
    val_ds = WindowDataset(dataset_dir, Split.VAL)
    for ds, name in ((train_ds, "train"), (val_ds, "validation")):
        if len(ds) == 0:
            raise DataError(f"the {name} split has no windows", path=mpath,
                            hint=f"assign at least one sequence with windows to split '{ds.split.value}' "
                                 "when running 'biasgt windows'")
    temperature = (0.0, 1.0)
    if config.use_temperature:
        if TEMPERATURE_KEY not in train_ds[0]:
            raise DataError(f"use_temperature is set but the windows carry no '{TEMPERATURE_KEY}'", path=mpath,
                            hint="re-create the dataset from sequences with IMU temperature, or set "
                                 "use_temperature: false")
        stats = manifest.get("normalization", {})
        key_m, key_s = "temperature_mean", "temperature_std"
        # the windows stage stores them as one-element lists (normalisation_stats: every channel a list)
        temperature = ((float(np.ravel(stats[key_m])[0]), float(np.ravel(stats[key_s])[0]))
                       if key_m in stats and key_s in stats else _temperature_stats(train_ds))
    normalizer = Normalizer.from_manifest(manifest, path=mpath, temperature_degc=temperature)
    gravity = {name: e["info"]["gravity_mps2"] for name, e in manifest["sequences"].items()
               if isinstance(e.get("info"), dict) and e["info"].get("gravity_mps2") is not None}
    info = {"format_version": manifest["format_version"], "window_samples": int(manifest["window_samples"]),
            "rate_hz": manifest.get("rate_hz"), "config_hash": manifest.get("config_hash"),
            "manifest_hash": hashlib.sha256(mpath.read_bytes()).hexdigest()[:16],
            "train_windows": len(train_ds), "val_windows": len(val_ds),
            # the sequences the model saw: evaluate refuses a test split that holds one of them
            "train_sequences": list(train_ds.sequences), "val_sequences": list(val_ds.sequences)}
    from training.context.model import ContextFeeder

    feeder = ContextFeeder.for_model(dataset_dir, config.model_config(), normalizer)  # None: no context read
    return _Data(train_ds, val_ds, manifest, info, normalizer, gravity, feeder)


def _model_config(config: TrainConfig, data: _Data) -> ModelConfig:
    """The model's config with a diffusion model's x0 clip resolved from the train and validation
    splits (:func:`training.models.clip.clip_bounds`)."""
    mc = config.model_config()
    if not mc.spec.is_diffusion or mc.clip_x0_bounds is not None:
        return mc
    stats = data.manifest["normalization"]
    biases = (ds.arrays(name)["bias"] for ds in (data.train, data.val) for name in ds.sequences)
    bounds = clip_bounds(mc, stats["bias_mean"], stats["bias_std"], biases)
    if bounds is not None:
        log.info("x0 clip (%s): lo %s, hi %s", mc.clip_x0_range.value, np.round(bounds[0], 6).tolist(),
                 np.round(bounds[1], 6).tolist())
    return replace(mc, clip_x0_bounds=bounds)


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        return torch.device(name)
    except RuntimeError:
        raise TrainingError(f"unknown device '{name}'", field="device", hint="use auto, cpu, cuda or cuda:N") from None


def _lr_lambda(warmup: int, total: int):
    """Linear warm-up from 0, then half a cosine down to 0 (diffusers' schedule)."""
    def f(step: int) -> float:
        if step < warmup:
            return step / max(1, warmup)
        progress = (step - warmup) / max(1, total - warmup)
        return max(0.0, 0.5 * (1.0 + math.cos(math.pi * progress)))
    return f


def _rng_state(noise: torch.Generator) -> dict[str, Any]:
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
             "noise": noise.get_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(state: dict[str, Any], noise: torch.Generator) -> None:
    torch.set_rng_state(state["torch"].cpu())
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    noise.set_state(state["noise"].cpu())
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])


def _loader_generator(seed: int) -> torch.Generator:
    """A DataLoader's own generator. Creating a loader's iterator draws its workers' base seed from
    the loader's generator, else from torch's global RNG, which dropout uses: with the global RNG a
    resumed run's first dropout masks would differ from the uninterrupted run's. The loaders read
    no random numbers otherwise (the batch order is :class:`BatchOrder`'s), so a fixed seed suffices
    and nothing of it needs checkpointing."""
    return torch.Generator().manual_seed(seed * 1_000_003 + 104_729)


def _seed_all(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)


@torch.no_grad()
def _validate(model: BiasModel, data: _Data, config: TrainConfig, device: torch.device) -> float:
    """Mean loss over the validation split (fixed noise: comparable between steps)."""
    was_training = model.training
    model.eval()
    g = torch.Generator().manual_seed(config.seed + 7919)
    loader = DataLoader(data.val, batch_size=config.batch_size, shuffle=False, collate_fn=data.collate,
                        num_workers=config.num_workers, generator=_loader_generator(config.seed))
    total, count = 0.0, 0
    for i, batch in enumerate(loader):
        if config.val_batches and i >= config.val_batches:
            break
        total += float(model.loss(batch.to(device), generator=g)) * len(batch)
        count += len(batch)
    model.train(was_training)
    return total / count


@dataclass
class _Run:
    """Mutable training state beyond the torch objects."""

    step: int = 0
    best_step: int = -1
    best_val_loss: float = math.inf
    seconds: float = 0.0  # training time (without validation and writing)
    windows: int = 0
    metrics: list[dict[str, Any]] = field(default_factory=list)
    losses: list[float] = field(default_factory=list)  # train losses since the last metrics row


def _write_metrics(out_dir: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(out_dir / METRICS, buf.getvalue())


class _Trainer:
    """One training run (the pieces :func:`train` wires together)."""

    def __init__(self, config: TrainConfig, data: _Data, out_dir: Path, rank: int, world: int) -> None:
        self.config, self.data, self.out_dir, self.rank, self.world = config, data, out_dir, rank, world
        self.device = _device(config.device)
        if world > 1 and self.device.type == "cuda":
            self.device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
        _seed_all(config.seed)
        self.model = build_model(_model_config(config, data), data.normalizer, config.indirect_weights).to(self.device)
        self.model.train()
        self.ddp = None
        if world > 1:
            self.ddp = torch.nn.parallel.DistributedDataParallel(
                self.model, device_ids=[self.device.index] if self.device.type == "cuda" else None)
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.lr_schedule = torch.optim.lr_scheduler.LambdaLR(self.optimizer,
                                                             _lr_lambda(config.warmup_steps, config.max_steps))
        self.ema = EMA(self.model, config.ema_decay, config.ema_power) if self.model.spec.is_diffusion else None
        self.noise = torch.Generator().manual_seed(config.seed + 1)
        self.run = _Run()

    # -- checkpoints -------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        r = self.run
        return {
            "format": CHECKPOINT_FORMAT, "step": r.step, "model": self.model.state_dict(),
            "ema": None if self.ema is None else self.ema.state_dict(),
            "optimizer": self.optimizer.state_dict(), "lr_schedule": self.lr_schedule.state_dict(),
            "rng": _rng_state(self.noise), "batch_order": {"seed": self.config.seed, "kind": "per-epoch randperm"},
            "config": self.config.to_dict(), "model_config": self.model.config.to_dict(),
            "normalizer": self.data.normalizer.stats(), "dataset": self.data.info,
            "best": {"step": r.best_step, "val_loss": r.best_val_loss},
            "progress": {"seconds": r.seconds, "windows": r.windows, "losses": list(r.losses)},
            "metrics": list(r.metrics),
        }

    def restore(self, state: dict[str, Any], path: Path) -> None:
        mismatch = [k for k, v in state["config"].items()
                    if k not in _RESUMABLE_CHANGES and self.config.to_dict().get(k) != v]
        if mismatch:
            raise TrainingError(f"cannot resume: options {', '.join(mismatch)} differ from the checkpoint's", path=path,
                                hint="resume with the run's own config or train into another --out")
        if state["dataset"]["manifest_hash"] != self.data.info["manifest_hash"]:
            raise TrainingError("cannot resume: the dataset differs from the one this run was trained on", path=path,
                                hint="resume with the same --dataset or train into another --out")
        self.model.load_state_dict(state["model"])
        if self.ema is not None:
            self.ema.load_state_dict(state["ema"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.lr_schedule.load_state_dict(state["lr_schedule"])
        _set_rng_state(state["rng"], self.noise)
        r = self.run
        r.step, r.best_step, r.best_val_loss = int(state["step"]), int(state["best"]["step"]), float(state["best"]["val_loss"])
        r.seconds, r.windows = float(state["progress"]["seconds"]), int(state["progress"]["windows"])
        r.losses = list(state["progress"]["losses"])
        r.metrics = list(state["metrics"])

    # -- steps -------------------------------------------------------------------------------------
    def train_step(self, batch: WindowBatch) -> float:
        loss = self._loss(batch)
        value = float(loss.detach()) if self.world == 1 else _global_mean(loss.detach())
        if not math.isfinite(value):
            kept = self.out_dir / LAST
            raise TrainingError(
                f"training loss is {value} at step {self.run.step + 1}", path=kept if kept.is_file() else None,
                hint=("the last good checkpoint is kept (this file); " if kept.is_file() else
                      "no checkpoint was written; ") + "lower lr (the training diverged)")
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.grad_clip)
        self.optimizer.step()
        self.lr_schedule.step()
        if self.ema is not None:
            self.ema.update(self.model)
        self.run.step += 1
        return value

    def _loss(self, batch: WindowBatch) -> torch.Tensor:
        if self.ddp is None:
            return self.model.loss(batch, self.noise)
        noise = t = None
        if self.model.spec.is_diffusion:  # every rank draws the global batch's noise and takes its share
            shape = (min(self.config.batch_size, len(self.data.train)), *self.model.state_shape(batch.bias.shape[1]))
            noise, t = self.model.draw_noise(shape, self.noise, self.device)
            noise, t = noise[self.rank::self.world], t[self.rank::self.world]
        return self.ddp(batch, noise=noise, t=t)  # DDP's hooks run on forward(), which is BiasModel.loss

    def eval_model(self) -> BiasModel:
        return self.ema.model if self.ema is not None else self.model

    def validate_and_record(self) -> float:
        r = self.run
        val = _validate(self.eval_model(), self.data, self.config, self.device)
        r.metrics.append({"step": r.step, "train_loss": float(np.mean(r.losses)) if r.losses else float("nan"),
                          "val_loss": val, "lr": self.lr_schedule.get_last_lr()[0], "seconds": round(r.seconds, 3)})
        if val < r.best_val_loss:
            r.best_val_loss, r.best_step = val, r.step
            save_checkpoint(self.state(), self.out_dir / BEST)
        _write_metrics(self.out_dir, r.metrics)
        return val


def _global_mean(x: torch.Tensor) -> float:
    """Mean of a scalar over the processes (the global batch's loss)."""
    import torch.distributed as dist

    y = x.clone()
    dist.all_reduce(y)
    return float(y) / dist.get_world_size()


def _progress(method: str, total: int, initial: int):
    """The training's progress bar: rate and ETA on a terminal, a log line every 30 s elsewhere."""
    from pipeline.progress import progress

    return progress(total, initial=initial, desc=f"train {method}", unit="step", logger=log)


def _distributed(device: str) -> tuple[int, int, bool]:
    """(rank, world size, whether this call started the process group) under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, False
    import torch.distributed as dist

    started = not dist.is_initialized()
    if started:
        dist.init_process_group("nccl" if _device(device).type == "cuda" else "gloo")
    return dist.get_rank(), dist.get_world_size(), started


def train(config: TrainConfig, dataset_dir: str | Path, out_dir: str | Path, *, resume: bool = False) -> Path:
    """Train ``config.method`` on ``dataset_dir`` into the run folder ``out_dir``.

    Args:
        config: Every training option.
        dataset_dir: A window dataset (``biasgt windows``); train and val splits are read.
        out_dir: Run folder (``last.pt``, ``best.pt``, ``metrics.csv``, ``run.json``).
        resume: Continue from ``out_dir/last.pt`` (a fresh start when there is none). With the
            same options the result is bit-identical to an uninterrupted run; a larger
            ``max_steps`` continues with the cosine schedule stretched to the new total (not the
            run a first start with that total would give).

    Returns:
        ``out_dir``.

    Raises:
        TrainingError: ``out_dir`` holds a run and ``resume`` is off; resume with other options or
            data; a non-finite loss (the last good checkpoint is kept).
        OutputLocationError: Another training holds ``out_dir`` (:func:`training.fit.run_folder.hold_run_folder`);
            the disk is full (:class:`pipeline.errors.NoSpaceError`: a run folder this call created is removed).
        DataError, InputFormatError: Empty train/val split, another dataset format, missing
            normaliser statistics or temperature.
    """
    dataset_dir, out_dir = Path(dataset_dir), Path(out_dir)
    if config.threads:
        torch.set_num_threads(config.threads)
    data = _open_data(config, dataset_dir)
    last = out_dir / LAST
    _refuse_finished(last, resume)
    rank, world, started = _distributed(config.device)
    if config.batch_size % world:
        raise TrainingError(f"batch_size {config.batch_size} is not divisible by {world} processes",
                            field="batch_size", hint="choose a global batch size divisible by the process count")
    try:
        # rank 0 writes, and holds the folder: a second training of it is refused (training.fit.run_folder)
        with hold_run_folder(out_dir) if rank == 0 else contextlib.nullcontext(out_dir):
            _refuse_finished(last, resume)  # again, now that no other training can write there
            trainer = _Trainer(config, data, out_dir, rank, world)
            if resume and last.exists():
                trainer.restore(load_checkpoint(last, trainer.device), last)
                log.info("resuming %s from step %d", out_dir, trainer.run.step)
            elif resume:
                log.info("nothing to resume in %s: starting afresh", out_dir)
            _fit(trainer)
    finally:
        if started:
            import torch.distributed as dist

            dist.destroy_process_group()
    return out_dir


def _refuse_finished(last: Path, resume: bool) -> None:
    if last.exists() and not resume:
        raise TrainingError("the run folder already holds a training run", path=last,
                            hint="pass --resume to continue it, or choose another --out")


def _fit(tr: _Trainer) -> None:
    config, run = tr.config, tr.run
    order = BatchOrder(len(tr.data.train), config.batch_size, config.seed, tr.rank, tr.world)
    if order.batch_size < config.batch_size and tr.rank == 0:
        log.warning("batch_size %d is larger than the train split (%d windows): every step uses all %d "
                    "(run.json: effective_batch_size)", config.batch_size, len(tr.data.train), order.batch_size)
    loader = DataLoader(tr.data.train, batch_sampler=_StepBatches(order, run.step, config.max_steps),
                        collate_fn=tr.data.collate, num_workers=config.num_workers,
                        generator=_loader_generator(config.seed))
    writer = tr.rank == 0
    log.info("training %s (%s preset, %d parameters) on %d windows, %d validation windows, %s",
             config.method, config.preset.value, count_parameters(tr.model), len(tr.data.train),
             len(tr.data.val), tr.device)
    bar = _progress(config.method, config.max_steps, run.step) if writer else None
    on_terminal = sys.stderr.isatty()
    tick = time.perf_counter()
    for batch in loader:
        run.losses.append(tr.train_step(batch.to(tr.device)))
        run.windows += order.batch_size
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{run.losses[-1]:.4g}", refresh=False)
        end = run.step == config.max_steps
        validate, save = run.step % config.val_every == 0 or end, run.step % config.checkpoint_every == 0 or end
        if not (validate or save):
            continue
        run.seconds += time.perf_counter() - tick
        if writer and validate:
            train_loss = float(np.mean(run.losses))
            val = tr.validate_and_record()
            if not on_terminal:
                log.info("step %d/%d  train loss %.5g  val loss %.5g  lr %.3g", run.step, config.max_steps,
                         train_loss, val, tr.lr_schedule.get_last_lr()[0])
        if validate:
            run.losses = []
        if writer and save:
            save_checkpoint(tr.state(), tr.out_dir / LAST)
        tick = time.perf_counter()
    if bar is not None:
        bar.close()
    if writer:
        _write_summary(tr)


def _write_summary(tr: _Trainer) -> None:
    r = tr.run
    summary = {
        "method": tr.config.method, "preset": tr.config.preset.value,
        "parameters": count_parameters(tr.model), "steps": r.step, "best_step": r.best_step,
        "effective_batch_size": min(tr.config.batch_size, len(tr.data.train)),
        "best_val_loss": r.best_val_loss, "train_seconds": round(r.seconds, 3),
        "windows_per_s": round(r.windows / r.seconds, 1) if r.seconds > 0 else None,
        "device": str(tr.device), "processes": tr.world, "dataset": tr.data.info, "config": tr.config.to_dict(),
    }
    write_text_atomic(tr.out_dir / RUN_JSON, json.dumps(summary, indent=2) + "\n")
    log.info("trained %s for %d steps; best validation loss %.5g at step %d", tr.config.method, r.step,
             r.best_val_loss, r.best_step)
