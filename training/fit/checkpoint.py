"""Training runs on disk: checkpoints (atomic), and loading a trained model back.

Run folder layout::

    RUN/last.pt       the latest state (every ``checkpoint_every`` steps and at the end)
    RUN/best.pt       the state with the lowest VALIDATION-split loss so far (never the test split)
    RUN/metrics.csv   step, train_loss, val_loss, lr, seconds
    RUN/run.json      method, preset, parameters, steps, best_step, best_val_loss, train_seconds,
                      windows_per_s, dataset manifest hash (written at the end)

A checkpoint is one ``torch.save`` dict (:data:`CHECKPOINT_FORMAT`): the model weights (with the
normaliser buffers), the EMA weights (diffusion models), optimiser and LR-schedule states, RNG
states (torch, numpy, python, the diffusion-noise generator; the batch order is a pure function
of seed and step), the step, the resolved :class:`TrainConfig` and :class:`ModelConfig`, the
normaliser statistics, the dataset's format version, window length, rate and manifest hash, the
best validation loss so far, the metrics rows and the SHA-256 of the weights (a damaged file is
refused, never predicted with). Evaluation and prediction rebuild everything
from it alone (:func:`load_run`).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pipeline.files.atomic import atomic_path
from pipeline.errors import BiasgtError
from training.config import ModelConfig, TrainConfig
from training.models.bias_model import BiasModel, build_model
from training.data.normalizer import Normalizer

log = logging.getLogger(__name__)

__all__ = ["CheckpointError", "LoadedRun", "load_run", "load_checkpoint", "save_checkpoint", "weights_hash",
           "check_finite_output", "CHECKPOINT_FORMAT", "LAST", "BEST", "METRICS", "RUN_JSON"]

CHECKPOINT_FORMAT = 1
LAST, BEST, METRICS, RUN_JSON = "last.pt", "best.pt", "metrics.csv", "run.json"


class CheckpointError(BiasgtError):
    """A checkpoint or run folder cannot be used."""


def save_checkpoint(state: dict[str, Any], path: str | Path) -> None:
    """Write ``state`` to ``path`` atomically (a temporary sibling renamed into place).

    The SHA-256 of the model weights (and of the EMA weights) is stored with them
    (``weights_sha256``), so that :func:`load_run` tells a damaged file from a trained model.
    """
    digests = {"model": weights_hash(state["model"])} if isinstance(state.get("model"), dict) else {}
    if isinstance(state.get("ema"), dict) and isinstance(state["ema"].get("model"), dict):
        digests["ema"] = weights_hash(state["ema"]["model"])
    with atomic_path(path) as tmp:
        torch.save({**state, "weights_sha256": digests}, tmp)


def load_checkpoint(path: str | Path, device: torch.device | str = "cpu") -> dict[str, Any]:
    """Read a checkpoint dict.

    Raises:
        CheckpointError: Missing, unreadable, of another checkpoint format, or weights that differ
            from their stored checksum.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError("checkpoint not found", path=path, hint="train a model with 'biasgt train'")
    try:
        state = torch.load(path, map_location=device, weights_only=False)
    except Exception as exc:  # torch raises many types for a truncated or foreign file
        raise CheckpointError(f"cannot read the checkpoint ({type(exc).__name__})", path=path,
                              hint="train again with 'biasgt train' (the file is damaged or not a checkpoint)") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        version = state.get("format") if isinstance(state, dict) else None
        raise CheckpointError(f"unsupported checkpoint format {version}", path=path,
                              hint="train again with this version's 'biasgt train'")
    try:
        _check_digests(state, path)
    except (AttributeError, TypeError, RuntimeError) as exc:  # a damaged pickle of odd types
        raise CheckpointError(f"checkpoint is corrupted ({type(exc).__name__})", path=path,
                              hint=_DAMAGED_HINT) from None
    return state


def weights_hash(state_dict: dict[str, torch.Tensor]) -> str:
    """SHA-256 of the weight tensors (names, dtypes, shapes and bytes, in sorted name order)."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
        h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.float().numpy().tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class LoadedRun:
    """A trained model rebuilt from a checkpoint.

    Attributes:
        model: EMA weights for diffusion models, the trained weights otherwise; eval mode.
        config: The resolved training config.
        dataset: ``format_version``, ``window_samples``, ``rate_hz``, ``manifest_hash``,
            ``config_hash`` of the dataset it was trained on.
        step: Optimiser step of the checkpoint.
        path: The checkpoint file.
    """

    model: BiasModel
    config: TrainConfig
    dataset: dict[str, Any]
    step: int
    path: Path


def _resolve(path: Path, which: str) -> Path:
    """The checkpoint file of a run folder (refused when its training never finished) or ``path`` itself."""
    if path.is_dir():
        if which not in ("best", "last"):
            raise CheckpointError(f"unknown checkpoint '{which}'", path=path, hint="use 'best' or 'last'")
        if not (path / RUN_JSON).is_file() and (path / LAST).is_file():
            raise CheckpointError(f"the run's training did not finish (no {RUN_JSON}: interrupted or failed)",
                                  path=path, hint="finish it with 'biasgt train --resume', or name one of its .pt "
                                                  "files to use that state anyway")
        return path / (BEST if which == "best" else LAST)
    return path


_DAMAGED_HINT = "the file is damaged: copy it again, or train again with 'biasgt train'"


def _check_digests(state: dict[str, Any], path: Path) -> None:
    """Refuse weights that differ from the checksums :func:`save_checkpoint` stored with them."""
    digests = state.get("weights_sha256") or {}
    for key, weights in (("model", state.get("model")), ("ema", (state.get("ema") or {}).get("model"))):
        if key in digests and (not isinstance(weights, dict) or weights_hash(weights) != digests[key]):
            raise CheckpointError(f"checkpoint is corrupted: its {key} weights do not match their stored checksum",
                                  path=path, hint=_DAMAGED_HINT)


def _check_finite(weights: dict[str, torch.Tensor], path: Path) -> None:
    """Refuse weights holding a non-finite number (a checkpoint written before checksums, damaged)."""
    for name, t in weights.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise CheckpointError(f"checkpoint is corrupted: weights '{name}' hold non-finite numbers", path=path,
                                  hint=_DAMAGED_HINT)


def load_run(path: str | Path, which: str = "best", device: torch.device | str = "cpu") -> LoadedRun:
    """Rebuild a trained model from a run folder (``which``: ``best`` or ``last``) or a ``.pt`` file.

    A run folder must hold the ``run.json`` its finished training writes; a ``.pt`` file named
    directly is used whatever state its run is in.

    Raises:
        CheckpointError: An unfinished run folder; missing or damaged file (checksum, non-finite
            weights), another format, or weights that do not fit.
    """
    file = _resolve(Path(path), which)
    state = load_checkpoint(file, device)
    try:
        config = TrainConfig.from_mapping(state["config"])
        model_config = ModelConfig.from_dict(state["model_config"])
        model = build_model(model_config, Normalizer(state["normalizer"]), config.indirect_weights)
        weights = state["ema"]["model"] if state.get("ema") is not None else state["model"]
        model.load_state_dict(weights)
    except (KeyError, TypeError, RuntimeError, BiasgtError) as exc:
        raise CheckpointError(f"checkpoint does not rebuild a model ({type(exc).__name__}: {exc})", path=file,
                              hint="train again with this version's 'biasgt train'") from None
    _check_finite(weights, file)
    model.to(device).eval()
    return LoadedRun(model=model, config=config, dataset=dict(state["dataset"]), step=int(state["step"]), path=file)


def check_finite_output(pred: np.ndarray, checkpoint: str | Path) -> None:
    """Refuse a model output holding NaN or inf (damaged weights, a diverged model), naming the checkpoint.

    Raises:
        CheckpointError: Some predicted value is not finite.
    """
    bad = ~np.isfinite(pred)
    if bad.any():
        raise CheckpointError(f"the model predicts non-finite bias ({int(bad.sum())} of {bad.size} values)",
                              path=checkpoint, hint="use another checkpoint, or train again with 'biasgt train' "
                                                    "(the weights are damaged or the training diverged)")
