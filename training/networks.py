"""The network registry: every learned method of the evaluation, one :class:`Network` entry each.

An entry owns everything that names a method: its name, Table I / report label, objective
(diffusion, regression, indirect), a help line (``biasgt train --help``), its colour and its
place (registration order) in Table I and the reports, its options dataclass (the architecture's
sizes, with values per size preset) and its factory. The CLI choices, the workflow's start-up
checks, Table I's order and the report colours read the registry; nothing else names a method.

The registry's form is :mod:`pipeline.registry`'s: the :data:`BUILTIN` tuple, :func:`register` and
:func:`unregister`, plugins found through the ``biasgt.networks`` entry points. Adding a network: a
module holding its ``nn.Module`` and, if it needs sizes other than an existing options class, a frozen
dataclass of them; then one :class:`Network` line in :data:`BUILTIN` below. The factory and the options
are given as ``"module:attr"`` and imported only when a plan names the method, so that this module
(read by ``--help`` and the workflow at start-up) imports no torch.

Factory contract: ``factory(config)`` with ``config`` a :class:`training.config.ModelConfig`
(shared fields plus this network's options, readable as ``config.network.<field>`` or
``config.<field>``) returns an ``nn.Module`` with

* diffusion: ``encode(condition [B, T, C_in]) -> code [B, C]`` and
  ``denoise(x_t [B, T, 6], t [B], code [B, C]) -> noise estimate [B, T, 6]``;
* regression / indirect: ``forward(condition [B, T, C_in]) -> normalised bias [B, T, 6]`` (a
  :attr:`Network.context` network: ``forward(condition, context [B, F])``).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.registry import Registry, resolve
from pipeline.errors import ConfigError

__all__ = ["BUILTIN", "NETWORKS", "Base", "ContextDiffusionOptions", "ContextLoss", "ContextOptions", "Network", "Objective", "RnnOptions", "UnetOptions", "get_network",
           "network_names", "register", "unregister"]


class Objective(str, enum.Enum):
    """How a network is trained and sampled (see :mod:`training.models`)."""

    DIFFUSION = "diffusion"  # DDPM, epsilon prediction; K samples per window
    REGRESSION = "regression"  # MSE on the normalised bias
    INDIRECT = "indirect"  # trained through the integrator against the reference end state, no bias labels


# ----------------------------------------------------------------------------- options of the built-in networks


@dataclass(frozen=True)
class TcnOptions:
    """Sizes of the TCN condition encoder and the diffusion-step embedding.

    Attributes:
        tcn_channels: Output channels of the TCN's temporal blocks (dilation 2^i in block i).
        tcn_kernel: TCN kernel size.
        tcn_dropout: Dropout inside the TCN blocks (the released code uses 0.2).
        cond_dim: Size of the condition code (last TCN timestep, projected).
        step_embed_dim: Size of the sinusoidal diffusion-step embedding (its MLP is 4x wider).
    """

    tcn_channels: tuple[int, ...] = (64, 64, 64, 64, 128, 128, 128)
    tcn_kernel: int = 2
    tcn_dropout: float = 0.2
    cond_dim: int = 256
    step_embed_dim: int = 256

    def __post_init__(self) -> None:
        object.__setattr__(self, "tcn_channels", tuple(int(c) for c in self.tcn_channels))


@dataclass(frozen=True)
class RnnOptions(TcnOptions):
    """TCN encoder + GRU trunk (the released code's RNN; defaults are its sizes).

    Attributes:
        hidden: GRU hidden size (also the fused input size).
        gru_layers: GRU layers.
    """

    hidden: int = 256
    gru_layers: int = 3


@dataclass(frozen=True)
class UnetOptions(TcnOptions):
    """TCN encoder + diffusion_policy's ConditionalUnet1D (defaults are the released code's sizes).

    Attributes:
        unet_dims: ConditionalUnet1D down dims.
        unet_kernel: ConditionalUnet1D kernel size.
        unet_groups: GroupNorm groups in the U-Net.
    """

    unet_dims: tuple[int, ...] = (256, 512, 1024)
    unet_kernel: int = 3
    unet_groups: int = 8

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "unet_dims", tuple(int(c) for c in self.unet_dims))
        bad = [d for d in self.unet_dims if d % self.unet_groups]
        if bad:
            raise ConfigError(f"U-Net dims {bad} are not multiples of unet_groups {self.unet_groups}",
                              field="unet_dims", hint="choose dims divisible by the GroupNorm groups")


class Base(str, enum.Enum):
    """The constant a context network's residual is added to (the one list of bases)."""

    NONE = "none"  # no base: the residual is the whole bias
    MEAN = "mean"  # the train split's mean bias (the train_mean row)
    REST = "rest"  # the start-rest estimate (the start_rest row, training/rows/start_rest.py)
    FILTER = "filter"  # the bias filter's gyro bias (training/rows/bias_filter.py), the train mean's accelerometer


class ContextLoss(str, enum.Enum):
    """What a context network is trained on."""

    LABEL = "label"  # the labels: MSE of the normalised bias (a diffusion network: its noise loss)
    INTEGRATION = "integration"  # the 1-s integration error, no label read
    BOTH = "both"  # their sum (label_weight times the label term)


@dataclass(frozen=True)
class ContextOptions:
    """The context networks (:mod:`training.context`): a constant base plus a residual from the window
    and what came before it in its sequence's record.

    Attributes:
        base: The constant the residual is added to (:class:`Base`).
        history_s: Spans (s) of the history means before the window (plus one since the record's
            start, and the time since it); empty: the start rest only.
        since_start: A history mean since the record's start too; None: with ``history_s`` only.
        filter: The bias filter's estimate and sigma in the context (always with base ``filter``).
        use_context: Give the context vector (False: zeros, the 1-s window's information alone).
        channels: Window encoder channels.
        hidden: Head width.
        loss: The training loss (:class:`ContextLoss`).
        label_weight: Weight of the label term (with ``both``).
        rot_scale_deg / pos_scale_m: The integration loss is ``mean(rot^2) / rot_scale^2 +
            mean(pos^2) / pos_scale^2`` (end errors of the windows; no velocity term). It replaces
            the training's ``indirect_weights``.
    """

    base: Base = Base.MEAN
    history_s: tuple[float, ...] = (5.0, 30.0)
    since_start: bool | None = None
    filter: bool = False
    use_context: bool = True
    channels: int = 32
    hidden: int = 64
    loss: ContextLoss = ContextLoss.INTEGRATION
    label_weight: float = 1.0
    rot_scale_deg: float = 0.1
    pos_scale_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "history_s", tuple(float(s) for s in self.history_s))
        for name, kind in (("base", Base), ("loss", ContextLoss)):
            try:
                object.__setattr__(self, name, kind(getattr(self, name)))
            except ValueError:
                raise ConfigError(f"context {name} '{getattr(self, name)}'", field=name,
                                  hint=f"use one of {', '.join(k.value for k in kind)}") from None
        if not (self.rot_scale_deg > 0 and self.pos_scale_m > 0):
            raise ConfigError("rot_scale_deg and pos_scale_m must be positive", field="rot_scale_deg")


@dataclass(frozen=True)
class ContextDiffusionOptions(ContextOptions):
    """The context residual drawn by a diffusion model (:mod:`training.context.diffusion`): the options of
    :class:`ContextOptions`, trained on its noise loss (``label``) or with the integration of its x0
    estimate too (``both``).

    Attributes:
        step_dim: Size of the diffusion step's embedding.
    """

    loss: ContextLoss = ContextLoss.LABEL
    step_dim: int = 32

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.loss is ContextLoss.INTEGRATION:
            raise ConfigError("a diffusion residual needs its noise loss: loss 'integration' alone trains no "
                              "diffusion model", field="loss",
                              hint="use 'label' (the noise loss) or 'both' (plus the integration of x0_hat)")


#: Preset values of the TCN encoder (``paper`` = the dataclass defaults).
_TCN_PRESETS = {"small": dict(tcn_channels=(32, 32, 32, 32, 64, 64, 64), cond_dim=64, step_embed_dim=64),
                "tiny": dict(tcn_channels=(16, 16, 16, 16), tcn_dropout=0.0, cond_dim=32, step_embed_dim=32)}
RNN_PRESETS = {"small": {**_TCN_PRESETS["small"], "hidden": 64, "gru_layers": 2},
               "tiny": {**_TCN_PRESETS["tiny"], "hidden": 64, "gru_layers": 2}}
UNET_PRESETS = {"small": {**_TCN_PRESETS["small"], "unet_dims": (32, 64, 128)},
                "tiny": {**_TCN_PRESETS["tiny"], "unet_dims": (16, 32, 64)}}


# ----------------------------------------------------------------------------- the registry


@dataclass(frozen=True)
class Network:
    """One learned method.

    Attributes:
        name: Method name (``--method``, the workflow's ``training.methods``, folder names).
        label: Name in Table I and the reports.
        objective: Diffusion, regression or indirect (:class:`Objective`).
        help: One line for ``biasgt train --help``.
        color: Matplotlib colour of the method in the reports.
        options: Frozen dataclass of the architecture's sizes (its defaults: the ``paper`` preset),
            or ``"module:attr"`` naming one.
        factory: ``"module:attr"`` of the network's constructor (see the module docstring), or a callable.
        presets: Preset name -> option values replacing the defaults (a preset not listed: the defaults).
        context: The network reads a context vector of each window from its sequence's record
            (``WindowBatch.context`` [B, F]; the dataset needs ``context/``, :mod:`training.data.records`):
            ``forward(condition [B, T, C_in], context [B, F])``.
    """

    name: str
    label: str
    objective: Objective
    help: str
    color: str
    options: type | str
    factory: str | Callable[[Any], Any]
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    context: bool = False
    default: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "objective", Objective(self.objective))

    @property
    def is_diffusion(self) -> bool:
        return self.objective is Objective.DIFFUSION

    @property
    def is_indirect(self) -> bool:
        return self.objective is Objective.INDIRECT

    def options_class(self) -> type:
        return resolve(self.options)

    def option_names(self) -> set[str]:
        return {f.name for f in dataclasses.fields(self.options_class())}

    def make_options(self, preset: str, **overrides: Any) -> Any:
        """The options of ``preset`` with ``overrides`` (keys of the options class) replacing single values."""
        return self.options_class()(**{**dict(self.presets.get(preset, {})), **overrides})

    def build(self, config: Any) -> Any:
        """The network's ``nn.Module`` for ``config`` (:class:`training.config.ModelConfig`)."""
        factory = resolve(self.factory)
        return factory(config)


# ----------------------------------------------------------------------------- built-in networks (Table I order)

BUILTIN = (
    Network("diffusion_rnn", "diffusion_rnn", Objective.DIFFUSION, "the paper's conditional diffusion model: TCN "
            "condition, GRU noise predictor", "#1f77b4", RnnOptions, "training.models.rnn:GruDenoiser", RNN_PRESETS),
    Network("regression_rnn", "regression_rnn", Objective.REGRESSION, "the same network, direct regression (MSE)",
            "#ff7f0e", RnnOptions, "training.models.rnn:GruRegressor", RNN_PRESETS),
    Network("diffusion_unet", "diffusion_unet", Objective.DIFFUSION, "TCN condition, 1-D conditional U-Net noise "
            "predictor", "#9467bd", UnetOptions, "training.models.unet:UnetDenoiser", UNET_PRESETS),
    Network("regression_unet", "regression_unet", Objective.REGRESSION, "the same U-Net, direct regression (MSE)",
            "#8c564b", UnetOptions, "training.models.unet:UnetRegressor", UNET_PRESETS),
    Network("indirect_rnn", "indirect_rnn", Objective.INDIRECT, "AirIMU-style: the RNN regressor trained through the "
            "IMU integrator, no bias labels", "#2ca02c", RnnOptions,
            "training.models.rnn:GruRegressor", RNN_PRESETS),
    Network("context_residual", "context_residual", Objective.INDIRECT, "train mean + a residual from the window "
            "and the means of the IMU record before it, trained through the integrator", "#d62728", ContextOptions,
            "training.context.model:ContextNet", context=True),
    Network("context_diffusion", "context_diffusion", Objective.DIFFUSION, "the context residual drawn by a "
            "conditional diffusion model (one residual per window) instead of regressed", "#e377c2",
            ContextDiffusionOptions, "training.context.diffusion:ContextDiffusionNet", context=True, default=False),
)


#: The registered networks by name, in registration (Table I) order.
NETWORKS: Registry[Network] = Registry("network", BUILTIN, entry_type=Network, noun="method")


def register(network: Network, *, before: str | None = None) -> Network:
    """Add ``network`` (at the end, or just before ``before``: its place in Table I).

    Raises:
        RegistryError: Its name is taken, or ``before`` is not registered.
    """
    return NETWORKS.register(network, before=before)


def unregister(name: str) -> None:
    """Remove a registered network (nothing when it is not registered)."""
    NETWORKS.unregister(name)


def network_names(*, default_only: bool = False) -> tuple[str, ...]:
    """Registered method names in registration (Table I) order (``default_only``: those a workflow trains
    when its ``training.methods`` is not given)."""
    return tuple(n for n, net in NETWORKS.items() if net.default or not default_only)


def get_network(name: Any, *, field: str = "method") -> Network:
    """The registered network ``name``.

    Raises:
        RegistryError: No network of that name (the hint lists the registered ones).
    """
    return NETWORKS.lookup(name, field=field)
