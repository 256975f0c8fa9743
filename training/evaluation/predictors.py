"""The evaluation's predictors: a reference row or a trained model, each asked for the bias of a batch of
test windows by one :class:`training.config.Draw` (samples, sampler, steps, seed)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from training.config import Draw, Sampler, SamplingBackend
from training.evaluation.windows import TestWindows
from training.fit.checkpoint import check_finite_output
from training.models.clip import ClipUse, clip_use
from training.networks import Network, get_network
from training.references import ReferenceRow

__all__ = ["ModelPredictor", "Predictor", "ReferencePredictor", "context_feeder"]


class Predictor(Protocol):
    """What the evaluation asks of a bias predictor."""

    name: str  # folder / column name (a registered method or reference row)
    label: str
    stochastic: bool  # draws different samples (a diffusion model)

    def predict(self, items: dict[str, Any], sequence: str, draw: Draw) -> np.ndarray:
        """Bias [B, K, T, 6] (rad/s, m/s^2) for windows of one sequence, ``K = draw.samples``."""


@dataclass
class ReferencePredictor:
    """A reference row (:class:`training.references.ReferenceRow`) as a predictor: it is given the
    inputs it declares (see :mod:`training.references`)."""

    row: ReferenceRow
    windows: TestWindows
    stochastic: bool = False

    @property
    def name(self) -> str:
        return self.row.name

    @property
    def label(self) -> str:
        return self.row.label

    def _input(self, need: str, items: dict[str, Any], sequence: str, seed: int) -> Any:
        w = self.windows
        if need == "bias_mean":
            return w.bias_mean
        if need == "bias_std":
            return np.asarray(w.manifest["normalization"]["bias_std"], dtype=np.float64)
        if need == "random_walk":
            return np.tile(w.random_walk[sequence], (len(items["imu"]), 1))
        if need == "gravity_mps2":
            return w.gravity_mps2[sequence]
        if need == "rng":
            return np.random.default_rng([seed, int(items["t0_ns"][0]) % (2**62)])
        if need == "context":
            from training.data.records import open_context

            return open_context(w.root, sequence)
        if need == "sequence_dir":
            return Path(w.root) / w.manifest["sequences"][sequence]["path"]
        if need.startswith("info."):
            value = w.manifest["sequences"][sequence].get("info", {}).get(need.removeprefix("info."))
            return None if value is None else np.asarray(value)
        return np.asarray(items[need], dtype=np.float64)

    def predict(self, items: dict[str, Any], sequence: str, draw: Draw) -> np.ndarray:
        inputs = {n: self._input(n, items, sequence, draw.seed) for n in self.row.needs}
        return self.row.predict({key: (v.numpy() if torch.is_tensor(v) else v) for key, v in items.items()}, inputs)


@dataclass
class ModelPredictor:
    """A trained model (:func:`training.fit.checkpoint.load_run`) as a predictor: its one prediction,
    :meth:`training.models.bias_model.BiasModel.sample` (chosen by the network's objective)."""

    run: Any  # training.fit.checkpoint.LoadedRun
    clip_counts: dict[Sampler, Any] = field(default_factory=dict)  # sampler -> training.models.scheduler.ClipCount
    context: Any = None  # a context network's training.context.model.ContextFeeder (:func:`context_feeder`)
    denoisers: dict[SamplingBackend, Any] = field(default_factory=dict)  # backend -> prepared denoiser (or None)

    @property
    def method(self) -> Network:
        return get_network(self.run.config.method)

    @property
    def name(self) -> str:
        return self.method.name

    @property
    def label(self) -> str:
        return self.method.label

    @property
    def stochastic(self) -> bool:
        return self.method.is_diffusion

    def predict(self, items: dict[str, Any], sequence: str, draw: Draw) -> np.ndarray:
        """Bias [B, K, T, 6]: the B windows drawn in chunks of ``draw.rows // K`` windows (one sampler
        call each), window b's noise from its own generator (seeded from ``draw.seed`` and its first
        stamp, :class:`training.models.scheduler.WindowNoise`), so the samples do not depend on the chunks."""
        from training.data.batch import WindowBatch
        from training.models.scheduler import ClipCount, WindowNoise

        model = self.run.model
        device = next(model.parameters()).device
        dtype = next(model.parameters()).dtype
        cast = {key: (v.to(dtype) if torch.is_tensor(v) and v.is_floating_point() else v) for key, v in items.items()}
        if self.context is not None:
            cast["context"] = self.context(items["sequence"], items["t0_ns"], items["imu"].shape[1]).to(dtype)
        noise = WindowNoise.seeded(draw.seed, [int(t) for t in items["t0_ns"]])
        kwargs = {}
        if draw.sampler is not None:
            kwargs = {"sampler": draw.sampler, "steps": draw.steps, "denoise": self._denoiser(draw.backend),
                      "clip_count": self.clip_counts.setdefault(Sampler(draw.sampler), ClipCount())}
        batch = WindowBatch.from_items(cast).to(device)
        per_call = max(1, int(draw.rows) // max(1, int(draw.samples)))
        outs = []
        for i in range(0, len(batch), per_call):
            out = model.sample(batch.rows(i, i + per_call), num_samples=draw.samples,
                               generator=noise.subset(i, i + per_call), **kwargs)
            outs.append(out.detach().to("cpu", torch.float64).numpy())
        out = np.concatenate(outs)
        check_finite_output(out, self.run.path)
        return out

    def _denoiser(self, backend: SamplingBackend) -> Any:
        """The model's denoiser run by ``backend`` (:func:`training.models.backends.prepare_denoiser`), prepared once."""
        backend = SamplingBackend(backend)
        if backend not in self.denoisers:
            from training.models.backends import prepare_denoiser

            self.denoisers[backend] = prepare_denoiser(self.run.model.net, backend)
        return self.denoisers[backend]

    def clip_use(self, sampler: Sampler | None) -> ClipUse | None:
        """How often ``sampler``'s clip bound over the predictions so far (None: not a diffusion model)."""
        count = None if sampler is None else self.clip_counts.get(Sampler(sampler))
        return None if count is None else clip_use(self.run.model, Sampler(sampler), count)


def context_feeder(run: Any, root: Path) -> Any:
    """A context network's feeder on the dataset ``root`` (the checkpoint's normaliser), else None.

    Raises:
        DataError: The network reads the records and the dataset has none.
    """
    from training.context.model import ContextFeeder

    return ContextFeeder.for_model(root, run.model.config, run.model.normalizer)
