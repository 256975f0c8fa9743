"""A bias network that sees what came before its window: a learned residual on a constant base.

Input of one window (causal: nothing after the window's last sample, :mod:`training.data.records`):

* the window itself, ``imu`` [T, 6] (and the temperature [T] with the temperature channel),
  normalised with the train split's statistics (the model's :class:`training.data.normalizer.Normalizer`);
* a context vector [F] (:func:`context_features`): the start-rest bias estimate
  (:mod:`training.rows.start_rest`, normalised) and whether a rest was seen, the rest's temperature,
  the mean IMU over the ``history_s`` seconds before the window and since the record's start
  (with the fraction of each span that exists), the time since the record's start, and the bias
  filter's estimate and sigma (:mod:`training.rows.bias_filter`) where asked.

:class:`ContextFeeder` gives each batch ``context`` [B, F + 6]: that vector, then the window's base
bias (:class:`training.networks.Base`, normalised). Output: one normalised bias [6] per window,
held over the window::

    bias_n = base_n + mlp(encoder(window), window mean, context) + linear(window mean, context)

The head's last layers start at zero, so an untrained network *is* its base and training learns a
correction (as AirIMU and Brossard's denoiser scale small corrections). The loss
(:class:`training.networks.ContextLoss`): the label MSE in normalised units, the 1-s integrated
rotation and position error from the reference start state (no label read), or their sum; the
model (:class:`training.models.bias_model.BiasModel`) reads its weights from the network.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from pipeline.types import DEFAULT_GRAVITY_MPS2
from training.rows.bias_filter import track_of
from pipeline.errors import DataError
from training.data.records import SequenceContext, has_context, open_context
from training.networks import Base, ContextLoss
from training.rows.start_rest import start_rest_bias

__all__ = ["ContextFeeder", "ContextInput", "ContextModelConfig", "ContextNet", "Stats", "WindowEncoder", "context_features",
           "loss_weights", "model_config_of"]


@dataclass(frozen=True)
class ContextModelConfig:
    """Inputs and sizes of a context network (:func:`model_config_of` its options).

    Attributes:
        base: The constant the residual is added to.
        history_s: Spans (s) of the history means before the window (plus the time since the
            record's start); empty: no history features (the start rest only).
        since_start: A history mean since the record's start too; None: with ``history_s`` only.
        filter: The bias filter's estimate and sigma at the window's end in the context
            (:mod:`training.rows.bias_filter`; on with ``base`` ``filter``).
        use_temperature: The window's temperature as a 7th channel and the rest's in the context.
        use_context: Give the context vector (False: zeros, the 1-s model's information).
        channels: Encoder channels.
        hidden: Head width.
    """

    base: Base = Base.REST
    history_s: tuple[float, ...] = (5.0, 30.0)
    since_start: bool | None = None
    filter: bool = False
    use_temperature: bool = False
    use_context: bool = True
    channels: int = 32
    hidden: int = 64

    def __post_init__(self) -> None:
        object.__setattr__(self, "base", Base(self.base))
        object.__setattr__(self, "history_s", tuple(float(s) for s in self.history_s))
        if self.base is Base.FILTER:
            object.__setattr__(self, "filter", True)

    def spans(self) -> tuple[float | None, ...]:
        """The history means' spans (s; None: since the record's start)."""
        since = bool(self.history_s) if self.since_start is None else self.since_start
        return (*self.history_s, *((None,) if since else ()))

    def features(self) -> int:
        """Size F of the context vector."""
        n = len(self.spans())
        return 6 + 1 + 1 + (6 * n + len(self.history_s) + 1 if n else 0) + (12 if self.filter else 0)


@dataclass(frozen=True)
class Stats:
    """Train-split statistics (the manifest's normalisation): [6] each, temperature mean/std scalars."""

    imu_mean: np.ndarray
    imu_std: np.ndarray
    bias_mean: np.ndarray
    bias_std: np.ndarray
    temperature_mean: float = 0.0
    temperature_std: float = 1.0

    @classmethod
    def from_manifest(cls, norm: dict) -> Stats:
        a = lambda k: np.asarray(norm[k], dtype=np.float64)  # noqa: E731
        tm = float(np.ravel(norm.get("temperature_mean", [0.0]))[0])
        ts = float(np.ravel(norm.get("temperature_std", [1.0]))[0])
        return cls(a("imu_mean"), a("imu_std"), a("bias_mean"), a("bias_std"), tm, max(ts, 1e-6))


def context_features(ctx: SequenceContext, t0_ns: np.ndarray, T: int, stats: Stats, config: ContextModelConfig,
                     gravity_norm_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """Context vectors [B, F] of windows starting at ``t0_ns`` [B] with ``T`` samples, and their
    base bias [B, 6] (raw units, :class:`Base`; the start rest's is the train mean where no rest is
    seen). Causal: reads samples before each window's end only."""
    start = ctx.index(t0_ns)
    stop = start + T
    rest_b, found = start_rest_bias(ctx, stop, stats.bias_mean, gravity_norm_mps2)
    parts = [(rest_b - stats.bias_mean) / stats.bias_std, found[:, None].astype(np.float64)]
    _, _, rest_t = ctx.rest_mean(stop)
    rt = np.zeros(len(start)) if rest_t is None or not config.use_temperature else np.nan_to_num(
        (rest_t - stats.temperature_mean) / stats.temperature_std)
    parts.append(rt[:, None])
    fills = []
    for span in config.spans():
        mean, fill = ctx.history_mean(start, None if span is None else int(round(span * ctx.rate_hz)))
        parts.append(np.where(fill[:, None] > 0, (mean - stats.imu_mean) / stats.imu_std, 0.0))
        if span is not None:
            fills.append(fill[:, None])
    parts.extend(fills)
    if config.spans():
        parts.append((start / ctx.rate_hz / 300.0)[:, None])
    filt = None
    if config.filter:
        track = track_of(ctx, stats.bias_mean, stats.bias_std, gravity_norm_mps2)
        filt = track.bias[stop - 1]
        parts.extend([(filt - stats.bias_mean) / stats.bias_std, track.std[stop - 1] / stats.bias_std])
    feats = np.concatenate(parts, axis=1)
    if not config.use_context:
        feats = np.zeros_like(feats)
    return feats, _base(config.base, rest_b, filt, stats.bias_mean)


def _base(base: Base, rest: np.ndarray, filt: np.ndarray | None, bias_mean: np.ndarray) -> np.ndarray:
    """The base bias [B, 6] of :class:`Base` ``base`` (``rest``, ``filt``: [B, 6] estimates)."""
    mean = np.tile(np.asarray(bias_mean, dtype=np.float64), (len(rest), 1))
    if base is Base.NONE:
        return np.zeros_like(mean)
    if base is Base.REST:
        return rest
    if base is Base.FILTER:
        assert filt is not None
        return np.concatenate([filt[:, :3], mean[:, 3:]], axis=1)
    return mean


class WindowEncoder(nn.Sequential):
    """Two strided convolutions over the normalised window; :meth:`summary` gives what a head reads."""

    #: Shortest window the encoder takes as it is; a shorter one is padded with its last sample.
    MIN_SAMPLES = 36

    def __init__(self, c_in: int, channels: int) -> None:
        super().__init__(nn.Conv1d(c_in, channels, 8, stride=4), nn.GELU(), nn.Conv1d(channels, channels, 8, stride=4),
                         nn.GELU())
        self.channels = channels

    def summary(self, x: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """``[code, mean(x), features]`` [B, channels + C + F] of the window ``x`` [B, T, C] and the
        context [B, F]; ``code`` is the encoder's output averaged over time."""
        xt = x.transpose(1, 2)
        if xt.shape[-1] < self.MIN_SAMPLES:
            xt = nn.functional.pad(xt, (0, self.MIN_SAMPLES - xt.shape[-1]), mode="replicate")
        return torch.cat([self(xt).mean(-1), x.mean(1), features.to(x)], dim=-1)


class _Residual(nn.Module):
    """The learned part: ``mlp(encoder(x), mean(x), features) + linear(mean(x), features)`` [B, 6]
    (normalised bias units) of the normalised window ``x`` [B, T, C] and the context [B, F]; the
    last layers start at zero."""

    def __init__(self, c_in: int, config: ContextModelConfig) -> None:
        super().__init__()
        c = config.channels
        self.encoder = WindowEncoder(c_in, c)
        self.head = nn.Sequential(nn.Linear(c + c_in + config.features(), config.hidden), nn.GELU(),
                                  nn.Linear(config.hidden, config.hidden), nn.GELU(), nn.Linear(config.hidden, 6))
        self.linear = nn.Linear(c_in + config.features(), 6)  # a linear path beside the MLP
        for last in (self.head[-1], self.linear):
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    def forward(self, x: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        full = self.encoder.summary(x, features)
        return self.head(full) + self.linear(full[:, self.encoder.channels:])


def model_config_of(config: Any) -> ContextModelConfig:
    """The :class:`ContextModelConfig` of a registered context network's
    :class:`training.config.ModelConfig` (options :class:`training.networks.ContextOptions`)."""
    o = config.network
    return ContextModelConfig(base=o.base, history_s=o.history_s, since_start=o.since_start, filter=o.filter,
                              use_temperature=config.condition_channels > 6, use_context=o.use_context,
                              channels=o.channels, hidden=o.hidden)


def loss_weights(options: Any) -> tuple[float, tuple[float, float, float]]:
    """``(label weight, integration weights)`` of a context network's options: the integration weights
    (rotation, velocity, position) are ``1 / rot_scale^2, 0, 1 / pos_scale^2`` (zero without the term)."""
    label = options.label_weight if options.loss in (ContextLoss.LABEL, ContextLoss.BOTH) else 0.0
    if options.loss is ContextLoss.LABEL:
        return float(label), (0.0, 0.0, 0.0)
    return float(label), (1.0 / math.radians(options.rot_scale_deg) ** 2, 0.0, 1.0 / options.pos_scale_m ** 2)


class ContextInput(nn.Module):
    """What every context network shares: its inputs (:func:`model_config_of` its options) and loss weights
    (:func:`loss_weights`), and the layout of the context a window carries: ``[vector F, base 6]``.

    Args:
        config: A :class:`training.config.ModelConfig` whose options are
            :class:`training.networks.ContextOptions`.
    """

    def __init__(self, config: Any) -> None:
        super().__init__()
        self.context_config = model_config_of(config)
        self.label_weight, self.integration_weights = loss_weights(config.network)

    @property
    def features(self) -> int:
        """Size F of the context vector (the base's six values follow it)."""
        return self.context_config.features()

    @property
    def context_size(self) -> int:
        """Size of the context each window carries: the vector, then the base's six values."""
        return self.features + 6

    def base(self, context: torch.Tensor) -> torch.Tensor:
        """The window's normalised base [B, 6]: the context's last six values."""
        return context[:, self.features:self.features + 6]


class ContextNet(ContextInput):
    """The context residual as a registered network (:mod:`training.networks`, objective indirect).

    ``forward(condition [B, T, C_in] normalised, context [B, F + 6]) -> normalised bias [B, T, 6]``,
    the window's one bias held over it: the base (the context's last six values, :class:`ContextFeeder`)
    plus the residual. ``label_weight`` and ``integration_weights`` (rotation, velocity, position) are
    the model's loss weights: they replace the training's ``indirect_weights``.

    Args:
        config: A :class:`training.config.ModelConfig` whose options are
            :class:`training.networks.ContextOptions`.
    """

    def __init__(self, config: Any) -> None:
        super().__init__(config)
        self.core = _Residual(config.condition_channels, self.context_config)

    def forward(self, condition: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        z = self.core(condition, context[:, :self.features]) + self.base(context).to(condition)
        return z[:, None].expand(-1, condition.shape[1], -1)


#: Gravity magnitude the context's start-rest estimate is computed with, in training and evaluation alike.
CONTEXT_GRAVITY_MPS2 = float(np.linalg.norm(DEFAULT_GRAVITY_MPS2))


@dataclass(frozen=True)
class ContextFeeder:
    """The context vectors of windows, read from a dataset's sequence records.

    ``feeder(sequences [B] names, t0_ns [B], T) -> context [B, F + 6]`` (float64 tensor, rows in the
    given order): :func:`context_features` with the nominal gravity magnitude, then the base bias
    normalised with the train statistics.
    """

    root: Path
    config: ContextModelConfig
    stats: Stats

    @classmethod
    def for_model(cls, root: str | Path, config: Any, normalizer: Any) -> ContextFeeder | None:
        """The feeder of a model of ``config`` (a :class:`training.config.ModelConfig`) on the dataset
        ``root``, with the statistics of its :class:`training.data.normalizer.Normalizer` (the train
        split's, as the checkpoint holds them); None for a network that reads no context.

        Raises:
            DataError: The network reads the records and the dataset has none.
        """
        if not config.spec.context:
            return None
        if not has_context(root):
            raise DataError(f"{config.method} reads the sequence records and the dataset has none", path=root,
                            hint="re-create the dataset with 'biasgt windows' (it writes context/), or write them "
                                 "with training.data.records.write_context")
        n = {k: getattr(normalizer, k).double().numpy() for k in ("imu_mean", "imu_std", "bias_mean", "bias_std")}
        stats = Stats(**n, temperature_mean=float(normalizer.temperature_mean),
                      temperature_std=float(normalizer.temperature_std))
        return cls(Path(root), model_config_of(config), stats)

    def __call__(self, sequences: Sequence[str], t0_ns: Any, T: int) -> torch.Tensor:
        t0 = np.asarray(t0_ns, dtype=np.int64).reshape(-1)
        names = np.asarray(list(sequences), dtype=object)
        F = self.config.features()
        out = np.zeros((len(t0), F + 6))
        for name in dict.fromkeys(names):
            rows = np.flatnonzero(names == name)
            feats, base = context_features(open_context(self.root, str(name)), t0[rows], T, self.stats, self.config,
                                           CONTEXT_GRAVITY_MPS2)
            out[rows, :F] = feats
            out[rows, F:] = (base - self.stats.bias_mean) / self.stats.bias_std
        return torch.from_numpy(out)
