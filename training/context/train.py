"""Train and evaluate :class:`training.context.model.ContextResidual` on a window dataset with records.

The dataset needs its sequence records (``context/``, :func:`training.data.records.write_context`).
Each split is loaded into memory once (windows, context features, base bias, gravity): the
train split of EuRoC is about 1,300 windows, 12 MB of IMU. Training: AdamW, cosine learning
rate, a batch order drawn from ``seed``; the validation split's loss every ``val_every`` steps
picks the kept weights. Evaluation: :func:`training.evaluation.evaluate.evaluate_predictor` on the test
split, the protocol of every row of Table I.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pipeline.atomic import write_text_atomic
from pipeline.errors import ConfigError
from pipeline.types import DEFAULT_GRAVITY_MPS2, Split
from training.config import EvalGravity, EvaluationConfig, Sampler
from training.context.diffusion import ContextDiffusion
from training.context.model import (
    ContextLoss,
    ContextModelConfig,
    ContextResidual,
    Stats,
    context_features,
    integration_errors,
)
from training.data.dataset import STATE_BIAS, TEMPERATURE, WindowDataset
from training.evaluation.evaluate import evaluate_predictor, load_test_windows
from training.evaluation.outputs import EvaluationResult, write_evaluation
from training.data.records import open_context

log = logging.getLogger(__name__)

__all__ = ["ContextPredictor", "ContextTrainConfig", "evaluate_context", "load_split", "train_context"]

_KEYS = ("imu", "bias", "start_R", "start_v", "start_p", "end_R", "end_p")


class LabelSource(str, enum.Enum):
    """What the label loss fits: the dataset's labels (the recovered bias), or the dataset's own
    ground-truth-state bias (:data:`training.data.dataset.STATE_BIAS`, EuRoC's) where a sequence has one
    and its labels elsewhere."""

    DATASET = "dataset"
    STATE = "state"


@dataclass(frozen=True)
class ContextTrainConfig:
    """Options of :func:`train_context`.

    Attributes:
        model: The model's inputs and sizes.
        loss: Label MSE, integration error, or both (:class:`ContextLoss`).
        steps / batch_size / lr / weight_decay / seed / val_every: The optimisation.
        gravity: Gravity of the integration loss (``nominal`` or each sequence's ``recovered``).
        rot_scale_deg / pos_scale_m: The integration loss is ``mean(rot^2) / rot_scale^2 +
            mean(pos^2) / pos_scale^2`` (end errors of the 1-s windows).
        label_weight: Weight of the label term in ``both``.
        labels: The label loss's target (:class:`LabelSource`).
    """

    model: ContextModelConfig = field(default_factory=ContextModelConfig)
    loss: ContextLoss = ContextLoss.LABEL
    steps: int = 600
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    seed: int = 0
    val_every: int = 50
    gravity: EvalGravity = EvalGravity.NOMINAL
    rot_scale_deg: float = 0.1
    pos_scale_m: float = 0.05
    label_weight: float = 1.0
    labels: LabelSource = LabelSource.DATASET

    def __post_init__(self) -> None:
        model = self.model if isinstance(self.model, ContextModelConfig) else ContextModelConfig(**dict(self.model))
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "loss", ContextLoss(self.loss))
        object.__setattr__(self, "gravity", EvalGravity(self.gravity))
        object.__setattr__(self, "labels", LabelSource(self.labels))
        if model.diffusion and self.loss is ContextLoss.INTEGRATION:
            raise ConfigError("a diffusion residual needs its noise loss: loss 'integration' alone trains no diffusion model",
                              field="loss", hint="use 'label' (the noise loss) or 'both' (plus the integration of x0_hat)")

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self), default=lambda o: getattr(o, "value", str(o))))


def _gravity(info: dict, mode: EvalGravity) -> np.ndarray:
    g = None if mode is EvalGravity.NOMINAL else info.get("gravity_mps2")
    return np.asarray(DEFAULT_GRAVITY_MPS2 if g is None else g, dtype=np.float64)


def load_split(root: str | Path, split: Split, stats: Stats, mc: ContextModelConfig,
               gravity: EvalGravity, labels: LabelSource = LabelSource.DATASET) -> dict[str, torch.Tensor]:
    """Every window of ``split`` in memory: ``_KEYS`` arrays, ``dt_s`` [W, T-1], ``features`` [W, F],
    ``base`` [W, 6], ``gravity`` [W, 3] and ``temperature_degc`` [W, T] when the dataset has it;
    ``bias`` [W, T, 6] from ``labels``."""
    ds = WindowDataset(root, split, dtype=torch.float64)
    out: dict[str, list[np.ndarray]] = {}
    for name in ds.sequences:
        a = ds.arrays(name)
        info = ds.manifest["sequences"][name].get("info") or {}
        g = _gravity(info, gravity)
        t_ns = np.asarray(a["t_ns"])
        feats, base = context_features(open_context(root, name), t_ns[:, 0], t_ns.shape[1],
                                       stats, mc, float(np.linalg.norm(g)))
        cols = {k: np.asarray(a[k], dtype=np.float64) for k in _KEYS}
        state_file = Path(root) / ds.manifest["sequences"][name]["path"] / f"{STATE_BIAS}.npy"
        state = np.load(state_file).astype(np.float64) if state_file.is_file() else None
        if labels is LabelSource.STATE and state is not None and np.all(np.isfinite(state)):
            cols["bias"] = state.reshape(cols["bias"].shape)
        cols["dt_s"] = np.diff(t_ns, axis=1) * 1e-9
        cols["features"] = feats
        cols["base"] = base
        cols["gravity"] = np.tile(g, (len(t_ns), 1))
        if TEMPERATURE in a:
            cols[TEMPERATURE] = np.asarray(a[TEMPERATURE], dtype=np.float64)
        for k, v in cols.items():
            out.setdefault(k, []).append(v)
    return {k: torch.from_numpy(np.concatenate(v)) for k, v in out.items()}


def _loss(model: ContextResidual | ContextDiffusion, d: dict[str, torch.Tensor], rows: torch.Tensor,
          config: ContextTrainConfig, generator: torch.Generator | None = None) -> torch.Tensor:
    x = {k: v[rows] for k, v in d.items()}
    total = torch.zeros((), dtype=torch.float64)
    weights = None
    if isinstance(model, ContextDiffusion):  # the noise MSE always; the integration of x0_hat with 'both'
        cond = model.condition(x["imu"].float(), x["features"].float(), x.get(TEMPERATURE))
        target = (x["bias"].mean(1) - x["base"]) / model.bias_std.double()
        eps_mse, x0, w = model.losses(cond, target.float(), generator)
        total = total + config.label_weight * eps_mse.double()
        pred, weights = model.unnormalise(x["base"].float(), x0), w.double()
    else:
        pred = model(x["imu"].float(), x["features"].float(), x["base"].float(), x.get(TEMPERATURE))
        if config.loss in (ContextLoss.LABEL, ContextLoss.BOTH):
            z = (pred.double()[:, None] - x["bias"]) / model.bias_std.double()
            total = total + config.label_weight * z.square().mean()
    if config.loss in (ContextLoss.INTEGRATION, ContextLoss.BOTH):
        values, group = torch.unique(x["gravity"], dim=0, return_inverse=True)
        rot_s, pos_s = math.radians(config.rot_scale_deg) ** 2, config.pos_scale_m ** 2
        for gi in range(len(values)):
            i = (group == gi).nonzero().squeeze(1)
            rot, pos = integration_errors(x["imu"][i], pred[i], x["dt_s"][i], x["start_R"][i], x["start_v"][i],
                                          x["start_p"][i], x["end_R"][i], x["end_p"][i], values[gi])
            if weights is None:
                total = total + (rot.sum() / rot_s + pos.sum() / pos_s) / len(rows)
            else:
                total = total + (weights[i] * (rot / rot_s + pos / pos_s)).sum() / len(rows)
    return total


def train_context(root: str | Path, config: ContextTrainConfig,
                  out_dir: str | Path | None = None) -> ContextResidual | ContextDiffusion:
    """Train on the train split, keep the weights of the best validation loss; write ``model.pt`` and
    ``run.json`` to ``out_dir`` when given. Returns the model (eval mode): a :class:`ContextDiffusion`
    with ``config.model.diffusion``, else a :class:`ContextResidual`."""
    t_start, cpu_start = time.perf_counter(), time.process_time()
    torch.manual_seed(config.seed)
    ds = WindowDataset(root, Split.TRAIN)
    stats = Stats.from_manifest(dict(ds.manifest.normalization))
    train = load_split(root, Split.TRAIN, stats, config.model, config.gravity, config.labels)
    val = load_split(root, Split.VAL, stats, config.model, config.gravity, config.labels)
    model = (ContextDiffusion if config.model.diffusion else ContextResidual)(config.model, stats)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.5 * (1 + math.cos(math.pi * min(s, config.steps) / config.steps)))
    gen = torch.Generator().manual_seed(config.seed)
    noise_gen = torch.Generator().manual_seed(config.seed + 1)  # the diffusion's steps and noise
    n = len(train["imu"])
    all_val = torch.arange(len(val["imu"]))

    def val_loss() -> float:
        model.eval()
        with torch.no_grad():  # the same steps and noise at every validation
            v = float(_loss(model, val, all_val, config, torch.Generator().manual_seed(config.seed + 2)))
        model.train()
        return v

    best, best_state, history = val_loss(), {k: v.clone() for k, v in model.state_dict().items()}, []
    best_step = 0
    for step in range(1, config.steps + 1):
        rows = torch.randint(0, n, (min(config.batch_size, n),), generator=gen)
        loss = _loss(model, train, rows, config, noise_gen)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % config.val_every == 0 or step == config.steps:
            v = val_loss()
            history.append({"step": step, "train_loss": float(loss.detach()), "val_loss": v})
            if v < best:
                best, best_step, best_state = v, step, {k: t.clone() for k, t in model.state_dict().items()}
    model.load_state_dict(best_state)
    model.eval()
    info = {"config": config.to_dict(), "best_step": best_step, "best_val_loss": best, "metrics": history,
            "train_windows": n, "val_windows": len(val["imu"]), "wall_s": round(time.perf_counter() - t_start, 2),
            "cpu_s": round(time.process_time() - cpu_start, 2)}
    log.info("context model: best validation loss %.5g at step %d of %d", best, best_step, config.steps)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        torch.save({"config": config.to_dict(), "state": model.state_dict()}, out / "model.pt")
        write_text_atomic(out / "run.json", json.dumps(info, indent=2) + "\n")
    model.info = info  # type: ignore[attr-defined]
    return model


@dataclass
class ContextPredictor:
    """A trained :class:`ContextResidual` or :class:`ContextDiffusion` as a :class:`training.evaluation.evaluate.Predictor`."""

    model: ContextResidual | ContextDiffusion
    root: Path
    gravity: dict[str, np.ndarray]
    stats: Stats
    name: str = "context_residual"
    label: str = "Context residual"

    @property
    def stochastic(self) -> bool:
        return isinstance(self.model, ContextDiffusion)

    @torch.no_grad()
    def predict(self, items: dict[str, Any], sequence: str, k: int, sampler: Any, seed: int) -> np.ndarray:
        """Biases [B, K, T, 6] (one per window, held over it); a diffusion model draws K by DDIM."""
        imu = items["imu"]
        B, T, _ = imu.shape
        ctx = open_context(self.root, sequence)
        t0 = np.asarray(items["t0_ns"], dtype=np.int64)
        feats, base = context_features(ctx, t0, T, self.stats, self.model.config,
                                       float(np.linalg.norm(self.gravity[sequence])))
        temp = items.get(TEMPERATURE)
        args = (imu.float(), torch.from_numpy(feats).float(), torch.from_numpy(base).float())
        temp = None if temp is None else temp.float()
        if self.stochastic:
            if sampler is not None and Sampler(sampler) is not Sampler.DDIM:
                raise ConfigError(f"the context diffusion model samples by DDIM only, not {sampler!r}",
                                  field="evaluation.samplers", hint="use samplers: [ddim]")
            gen = torch.Generator().manual_seed(seed * 1_000_003 + int(t0[0]) % 1_000_003)
            out = self.model.sample(*args, k, temp, gen).double().numpy()  # [B, K, 6]
        else:
            out = self.model(*args, temp).double().numpy()[:, None]  # [B, 1, 6]
        return np.broadcast_to(out[:, :, None, :], (B, out.shape[1], T, 6)).copy()


def evaluate_context(model: ContextResidual | ContextDiffusion, root: str | Path, config: EvaluationConfig = EvaluationConfig(),
                     out_dir: str | Path | None = None, *, name: str = "context_residual") -> EvaluationResult:
    """Table I's protocol on the test split (:func:`training.evaluation.evaluate.evaluate_predictor`); written to
    ``out_dir`` when given."""
    windows = load_test_windows(root, config)
    stats = Stats.from_manifest(dict(windows.dataset.manifest.normalization))
    predictor = ContextPredictor(model, Path(root), dict(windows.gravity_mps2), stats, name=name)
    result = evaluate_predictor(predictor, windows, config, kind="learned", checkpoint=getattr(model, "info", {}))
    if out_dir is not None:
        write_evaluation(result, out_dir)
    return result
