"""A bias model that sees what came before its window: a learned residual on a constant baseline.

Input of one window (causal: nothing after the window's last sample, :mod:`training.data.records`):

* the window itself, ``imu`` [T, 6] (and the temperature [T] with ``use_temperature``), normalised
  with the train split's statistics;
* a context vector [F] (:func:`context_features`): the start-rest bias estimate
  (:mod:`training.rows.start_rest`, normalised) and whether a rest was seen, the rest's temperature,
  the mean IMU over the ``history_s`` seconds before the window and since the record's start
  (with the fraction of each span that exists), and the time since the record's start.

Output: one bias [6] per window, held over the window (rad/s, m/s^2)::

    bias = base + bias_std * (mlp(encoder(window), window mean, context) + linear(window mean, context))

``base`` is the train mean or the start-rest estimate; the head's last layer starts at zero, so an
untrained model *is* its base and training learns a correction (as AirIMU and Brossard's denoiser
scale small corrections). Losses (:class:`ContextLoss`): the label MSE in normalised units, the
1-s integrated rotation and position error from the reference start state through the project's
torch integrator (:func:`integration_errors`, no label read), or their sum.

Two ways to train it: :mod:`training.context.train` (the benchmarks' trainer, three losses), or as
the registered network :class:`ContextNet` (``biasgt train``; integration loss), whose batches
carry the context vectors from :class:`ContextFeeder`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from pipeline.geometry.integration import integrate
from pipeline.geometry.so3_torch import so3_log
from pipeline.types import DEFAULT_GRAVITY_MPS2
from training.rows.bias_filter import track_of
from training.data.records import SequenceContext, open_context
from training.rows.start_rest import start_rest_bias

__all__ = ["Base", "ContextFeeder", "ContextLoss", "ContextModelConfig", "ContextNet", "ContextResidual",
           "NormalisedInput", "WindowEncoder", "context_features", "integration_errors"]


class Base(str, enum.Enum):
    """The constant the residual is added to."""

    NONE = "none"  # no base: the residual is the whole bias (the benchmarks' trainer only)
    MEAN = "mean"  # the train split's mean bias (the train_mean row)
    REST = "rest"  # the start-rest estimate (the start_rest row, training/rows/start_rest.py)
    FILTER = "filter"  # the bias filter's gyro bias (training/rows/bias_filter.py), the train mean's accelerometer


class ContextLoss(str, enum.Enum):
    """Training loss (module docstring)."""

    LABEL = "label"
    INTEGRATION = "integration"
    BOTH = "both"


@dataclass(frozen=True)
class ContextModelConfig:
    """Sizes and inputs of :class:`ContextResidual`.

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
        diffusion: Draw the residual from a conditional diffusion model
            (:class:`training.context.diffusion.ContextDiffusion`) instead of regressing it.
    """

    base: Base = Base.REST
    history_s: tuple[float, ...] = (5.0, 30.0)
    since_start: bool | None = None
    filter: bool = False
    use_temperature: bool = False
    use_context: bool = True
    channels: int = 32
    hidden: int = 64
    diffusion: bool = False

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


class NormalisedInput(nn.Module):
    """The train split's statistics as buffers, and the window normalised with them.

    Args:
        config: Sizes and inputs (``use_temperature`` adds the temperature channel).
        stats: Train-split statistics.
    """

    def __init__(self, config: ContextModelConfig, stats: Stats) -> None:
        super().__init__()
        self.config = config
        self.c_in = 6 + (1 if config.use_temperature else 0)
        for name in ("imu_mean", "imu_std", "bias_mean", "bias_std"):
            self.register_buffer(name, torch.tensor(getattr(stats, name), dtype=torch.float32))
        self.register_buffer("temperature", torch.tensor([stats.temperature_mean, stats.temperature_std]))

    def normalise(self, imu: torch.Tensor, temperature_degc: torch.Tensor | None = None) -> torch.Tensor:
        """The normalised window [B, T, C] of raw ``imu`` [B, T, 6] (and the temperature [B, T] as a
        7th channel with ``use_temperature``)."""
        x = (imu - self.imu_mean) / self.imu_std
        if self.config.use_temperature:
            t = (temperature_degc - self.temperature[0]) / self.temperature[1]
            x = torch.cat([x, t.unsqueeze(-1).to(x)], dim=-1)
        return x


class ContextResidual(NormalisedInput):
    """``bias = base + bias_std * (mlp(...) + linear(...))`` (module docstring).

    Args:
        config: Sizes and inputs.
        stats: Train-split statistics (stored as buffers).
    """

    def __init__(self, config: ContextModelConfig, stats: Stats) -> None:
        super().__init__(config, stats)
        self.core = _Residual(self.c_in, config)

    def forward(self, imu: torch.Tensor, features: torch.Tensor, base: torch.Tensor,
                temperature_degc: torch.Tensor | None = None) -> torch.Tensor:
        """Bias [B, 6] (raw units) from ``imu`` [B, T, 6], ``features`` [B, F], ``base`` [B, 6] and the
        temperature [B, T] (with ``use_temperature``)."""
        x = self.normalise(imu, temperature_degc)
        return base.to(x) + self.core(x, features) * self.bias_std


def model_config_of(config: Any) -> ContextModelConfig:
    """The :class:`ContextModelConfig` of a registered context network's
    :class:`training.config.ModelConfig` (options :class:`training.networks.ContextOptions`)."""
    o = config.network
    return ContextModelConfig(base=o.base, history_s=o.history_s, filter=o.filter,
                              use_temperature=config.condition_channels > 6, channels=o.channels, hidden=o.hidden)


class ContextNet(nn.Module):
    """The context residual as a registered network (:mod:`training.networks`, objective indirect).

    ``forward(condition [B, T, C_in] normalised, context [B, F]) -> normalised bias [B, T, 6]``,
    the window's one bias held over it: ``base + residual``, with ``base`` zero (the train mean),
    the context's first six values (the start-rest estimate, normalised) or the filter block's gyro
    (the bias filter's gyro, the train mean's accelerometer). ``context`` is
    :class:`ContextFeeder`'s. ``integration_weights`` (rotation, velocity, position) replace the
    training's ``indirect_weights``: ``1 / rot_scale^2, 0, 1 / pos_scale^2``.

    Args:
        config: A :class:`training.config.ModelConfig` whose options are
            :class:`training.networks.ContextOptions`.
    """

    def __init__(self, config: Any) -> None:
        super().__init__()
        self.context_config = model_config_of(config)
        o = config.network
        self.integration_weights = (1.0 / math.radians(o.rot_scale_deg) ** 2, 0.0, 1.0 / o.pos_scale_m ** 2)
        self.core = _Residual(config.condition_channels, self.context_config)

    @property
    def features(self) -> int:
        """Size F of the context vector."""
        return self.context_config.features()

    def forward(self, condition: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        z = self.core(condition, context)
        if self.context_config.base is Base.REST:
            z = z + context[:, :6].to(z)
        elif self.context_config.base is Base.FILTER:  # the filter block closes the vector: bias then sigma
            gyro = context[:, -12:-9].to(z)
            z = z + torch.cat([gyro, torch.zeros_like(gyro)], dim=-1)
        return z[:, None].expand(-1, condition.shape[1], -1)


#: Gravity magnitude the context's start-rest estimate is computed with, in training and evaluation alike.
CONTEXT_GRAVITY_MPS2 = float(np.linalg.norm(DEFAULT_GRAVITY_MPS2))


@dataclass(frozen=True)
class ContextFeeder:
    """The context vectors of windows, read from a dataset's sequence records.

    ``feeder(sequences [B] names, t0_ns [B], T) -> context [B, F]`` (float64 tensor, rows in the
    given order; :func:`context_features` with the nominal gravity magnitude).
    """

    root: Path
    config: ContextModelConfig
    stats: Stats

    @classmethod
    def for_model(cls, root: str | Path, config: ContextModelConfig, normalizer: Any) -> ContextFeeder:
        """The feeder of a model of ``config`` (:func:`model_config_of`) on the dataset ``root``, with
        the statistics of its :class:`training.data.normalizer.Normalizer` (the train split's, as the
        checkpoint holds them)."""
        n = {k: getattr(normalizer, k).double().numpy() for k in ("imu_mean", "imu_std", "bias_mean", "bias_std")}
        stats = Stats(**n, temperature_mean=float(normalizer.temperature_mean),
                      temperature_std=float(normalizer.temperature_std))
        return cls(Path(root), config, stats)

    def __call__(self, sequences: Sequence[str], t0_ns: Any, T: int) -> torch.Tensor:
        t0 = np.asarray(t0_ns, dtype=np.int64).reshape(-1)
        names = np.asarray(list(sequences), dtype=object)
        out = np.zeros((len(t0), self.config.features()))
        for name in dict.fromkeys(names):
            rows = np.flatnonzero(names == name)
            out[rows], _ = context_features(open_context(self.root, str(name)), t0[rows], T, self.stats, self.config,
                                            CONTEXT_GRAVITY_MPS2)
        return torch.from_numpy(out)


def integration_errors(imu: torch.Tensor, bias: torch.Tensor, dt_s: torch.Tensor, start_R: torch.Tensor,
                       start_v: torch.Tensor, start_p: torch.Tensor, end_R: torch.Tensor, end_p: torch.Tensor,
                       gravity_mps2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared end rotation error [B] (rad^2, ``|Log(R_gt^T R)|^2``) and squared end position error [B]
    (m^2) of windows integrated (float64, :func:`pipeline.geometry.integration.integrate`, differentiable)
    from their reference start with ``imu - bias`` (``bias`` [B, 6] held, or [B, T, 6]); one gravity [3]."""
    f64 = torch.float64
    imu = imu.to(f64)
    b = bias.to(f64)
    if b.dim() == 2:
        b = b[:, None].expand_as(imu)
    res = integrate(imu[..., :3], imu[..., 3:], dt_s.to(f64), start_R.to(f64), start_v.to(f64), start_p.to(f64),
                    gravity_mps2=gravity_mps2.to(f64), bias_gyro_radps=b[..., :3], bias_acc_mps2=b[..., 3:])
    rot = so3_log(end_R.to(f64).transpose(-1, -2) @ res.R).square().sum(-1)
    pos = (res.p - end_p.to(f64)).square().sum(-1)
    return rot, pos
