"""Typed configuration of the learning stage: methods, size presets, samplers, training options.

Every option and its default is defined once, here. ``ModelConfig`` holds a model's method, its
network's options (:mod:`training.networks`: each network's own dataclass and preset values;
:meth:`ModelConfig.for_preset` gives a preset's) and the diffusion schedule; ``TrainConfig`` holds every training
option (a YAML ``training:`` section or a ``--config`` file maps onto it with
:meth:`TrainConfig.from_mapping`).

Presets:
    * ``paper``: the released code's sizes (ShenghaoZhou/ioo_diffusion): the RNN denoiser has
      2,192,710 parameters (GRU with 3 layers; the paper text says 2), the U-Net 42,814,022.
      Meant for a GPU.
    * ``small``: a CPU preset; trains a ``make run``-sized dataset in about a minute per method
      on 2 cores.
    * ``tiny``: for tests; trains in seconds.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.configs import dataclass_from_mapping, dataclass_to_mapping
from pipeline.files.jsonio import to_plain
from pipeline.errors import ConfigError
from training.networks import Network, get_network, network_names
from training.references import get_reference, reference_names

__all__ = ["Preset", "Sampler", "SamplingBackend", "ClipRange", "ModelConfig", "TrainConfig", "IMU_CHANNELS", "SAMPLES", "STEPS"]

#: Channels of one IMU sample and of one bias sample: gyro x, y, z (rad/s), acc x, y, z (m/s^2).
IMU_CHANNELS = 6
#: Samples a diffusion model draws per window unless told (the paper's K): evaluation, prediction.
SAMPLES = 50
#: Denoising steps of a diffusion model's sampler unless told: evaluation, prediction, export.
STEPS = 25


class Preset(str, enum.Enum):
    """Named network sizes (see the module docstring)."""

    PAPER = "paper"
    SMALL = "small"
    TINY = "tiny"


class Sampler(str, enum.Enum):
    """How a diffusion model draws samples."""

    DDIM = "ddim"  # correct DDIM (Song et al. 2021), eta 0 by default, spread over the 1000 steps
    RELEASED = "released"  # the released code's sampler: t = S-1..0, each step the clipped x0 estimate
    DDPM = "ddpm"  # ancestral DDPM over the given number of steps


class SamplingBackend(str, enum.Enum):
    """How a diffusion model's denoiser is run while sampling (:mod:`training.models.backends`).

    ``exact`` is PyTorch's float32 eager arithmetic: its samples are the reference, the same for the
    same seed however the windows are batched. ``bf16`` changes the arithmetic for speed, and its
    samples are equal to ``exact``'s in distribution only (tested).
    """

    EXACT = "exact"  # float32, eager PyTorch (the default)
    BF16 = "bf16"  # bfloat16 autocast (AMX / AVX512-BF16 matrix units), compiled by torch.compile


class ClipRange(str, enum.Enum):
    """Where the DDIM / DDPM samplers clip each step's x0 estimate, per channel (see ``ModelConfig``)."""

    EVIDENCE = "evidence"  # the train mean +- (largest |bias - mean| in the train and validation splits + margin)
    TRAIN = "train"  # the train mean +- clip_x0_sigmas train sigmas (diffusers' clip_sample on the z-scored bias)
    SENSOR = "sensor"  # +- clip_x0_bias_range about zero: the sensor's stated bias range (raw units)


@dataclass(frozen=True)
class ModelConfig:
    """The method, its network's sizes and the diffusion schedule of one model.

    Attributes:
        method: Which model: a registered network name (:mod:`training.networks`).
        preset: Which size preset the values came from (informative).
        condition_channels: Input channels of the condition encoder: 6 (gyro, acc) or 7 (plus
            the IMU temperature).
        network: The network's own options (its :attr:`training.networks.Network.options`
            dataclass; a mapping is read into it; ``None``: the preset's). Its fields read as
            attributes of the config too (``config.hidden``).
        train_timesteps: Diffusion steps of the forward process.
        beta_start: First beta of the linear schedule.
        beta_end: Last beta of the linear schedule.
        clip_sample: Clip range of the x0 estimate in the RELEASED sampler, in raw units (rad/s,
            m/s^2) as the released code does.
        clip_x0_range: DDIM and DDPM clip each step's x0 estimate (diffusers' ``clip_sample``, per
            channel and in raw units here) to stop estimates that run away at high noise levels
            (see :mod:`training.models.scheduler`). The clip applies at the last step too, so no sample
            leaves it: it must hold every bias the model may need to predict. ``evidence``
            (default): the train mean +- (the largest distance of a train or validation bias
            from it + ``clip_x0_sigmas`` train sigmas); a validation sequence whose bias lies
            far from the training biases widens it. ``train``: the train mean +-
            ``clip_x0_sigmas`` train sigmas (the earlier default; a bias beyond it cannot be
            predicted). ``sensor``: +- ``clip_x0_bias_range`` about zero. Training resolves the
            range into ``clip_x0_bounds``; the evaluation reports how often it binds.
        clip_x0_sigmas: Margin of the ``evidence`` range and half-width of the ``train`` range, in
            sigmas of the train split's bias (``None``: no clipping in any mode).
        clip_x0_bias_range: ``sensor`` range: half-widths of the bias about zero, gyro x, y, z
            (rad/s) then acc x, y, z (m/s^2), e.g. the datasheet's initial bias tolerance.
        clip_x0_bounds: The resolved range, ``(lo, hi)`` of 6 raw-unit values each (set by
            training; ``None``: the ``train`` range, as models built outside training use).
    """

    method: str
    preset: Preset = Preset.SMALL
    condition_channels: int = IMU_CHANNELS
    network: Any = None
    train_timesteps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    clip_sample: float = 1.0
    clip_x0_sigmas: float | None = 3.0
    clip_x0_range: ClipRange = ClipRange.EVIDENCE
    clip_x0_bias_range: tuple[float, ...] | None = None
    clip_x0_bounds: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def __post_init__(self) -> None:
        net = get_network(self.method)
        object.__setattr__(self, "method", net.name)
        if self.clip_x0_sigmas is not None and not float(self.clip_x0_sigmas) > 0:
            raise ConfigError(f"clip_x0_sigmas must be positive or null, got {self.clip_x0_sigmas!r}",
                              field="clip_x0_sigmas", hint="e.g. 3 (sigmas of the train split's bias), or null for none")
        self._check_clip()
        object.__setattr__(self, "preset", Preset(self.preset))
        object.__setattr__(self, "network", _network_options(net, self.network, self.preset))
        if self.condition_channels not in (IMU_CHANNELS, IMU_CHANNELS + 1):
            raise ConfigError(f"condition_channels is {self.condition_channels}", field="condition_channels",
                              hint="use 6 (gyro, acc) or 7 (plus temperature)")

    def __getattr__(self, name: str) -> Any:
        """A field of the network's options (``config.hidden``); only called for names not on the config."""
        network = self.__dict__.get("network")
        if not name.startswith("_") and network is not None and hasattr(network, name):
            return getattr(network, name)
        raise AttributeError(f"{type(self).__name__} of {self.__dict__.get('method')!r} has no option {name!r}")

    @property
    def spec(self) -> Network:
        """The method's registry entry (:class:`training.networks.Network`)."""
        return get_network(self.method)

    def _check_clip(self) -> None:
        try:
            object.__setattr__(self, "clip_x0_range", ClipRange(self.clip_x0_range))
        except ValueError:
            raise ConfigError(f"unknown clip_x0_range '{self.clip_x0_range}'", field="clip_x0_range",
                              hint=f"choose one of {', '.join(c.value for c in ClipRange)}") from None
        r = self.clip_x0_bias_range
        if r is not None:
            r = tuple(float(v) for v in r)
            if len(r) != IMU_CHANNELS or not all(v > 0 for v in r):
                raise ConfigError(f"clip_x0_bias_range needs {IMU_CHANNELS} positive numbers, got {list(r)}",
                                  field="clip_x0_bias_range", hint="gyro x, y, z (rad/s) then acc x, y, z (m/s^2)")
            object.__setattr__(self, "clip_x0_bias_range", r)
        if self.clip_x0_range is ClipRange.SENSOR and r is None and self.clip_x0_sigmas is not None:
            raise ConfigError("clip_x0_range 'sensor' needs clip_x0_bias_range", field="clip_x0_bias_range",
                              hint="give the sensor's bias range: 6 half-widths, gyro (rad/s) then acc (m/s^2)")
        if self.clip_x0_bounds is not None:
            lo, hi = (tuple(float(v) for v in b) for b in self.clip_x0_bounds)
            if len(lo) != IMU_CHANNELS or len(hi) != IMU_CHANNELS or not all(a < b for a, b in zip(lo, hi)):
                raise ConfigError("clip_x0_bounds needs (lo, hi) of 6 values each with lo < hi",
                                  field="clip_x0_bounds", hint="leave it unset: training resolves it")
            object.__setattr__(self, "clip_x0_bounds", (lo, hi))

    @classmethod
    def shared_options(cls) -> set[str]:
        """Options of every method (the schedule and the clip), as opposed to the network's own."""
        return {f.name for f in dataclasses.fields(cls)} - {"method", "preset", "condition_channels", "network"}

    @classmethod
    def for_preset(cls, method: str, preset: Preset | str, **overrides: Any) -> ModelConfig:
        """The sizes of ``preset`` for ``method``; ``overrides`` replace single values (the network's
        options or the shared ones).

        Raises:
            ConfigError: Unknown method, or an override that is neither a shared nor a network option.
        """
        net, preset = get_network(method), Preset(preset)
        own = cls.shared_options() | {"condition_channels"}
        unknown = sorted(set(overrides) - own - net.option_names())
        if unknown:
            raise ConfigError(f"unknown {net.name} option(s) {', '.join(unknown)}", field="model_overrides",
                              hint=f"allowed: {', '.join(sorted(cls.shared_options() | net.option_names()))}")
        network = net.make_options(preset.value, **{k: v for k, v in overrides.items() if k not in own})
        return cls(method=net.name, preset=preset, network=network, **{k: v for k, v in overrides.items() if k in own})

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping; the network's options nested under ``network``."""
        return dataclass_to_mapping(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ModelConfig:
        """From :meth:`to_dict`, or from the flat mapping of a checkpoint written before the options were
        per network (every architecture's sizes side by side: this network's are kept, the rest dropped)."""
        d = dict(d)
        if "network" not in d:
            names = get_network(d.get("method")).option_names()
            d["network"] = {k: d[k] for k in names if k in d}
            own = {f.name for f in dataclasses.fields(cls)}
            d = {k: v for k, v in d.items() if k in own}
        return cls(**d)


def check_model_overrides(overrides: Iterable[str], methods: Iterable[str]) -> None:
    """Refuse model options that are neither shared nor an option of one of ``methods``' networks (only
    their options are read: a network's options class is imported when a plan names it).

    Raises:
        ConfigError: An unknown option; the hint lists the allowed ones.
    """
    known = ModelConfig.shared_options().union(*(get_network(m).option_names() for m in methods))
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ConfigError(f"unknown model option(s) {', '.join(unknown)}", field="model_overrides",
                          hint=f"allowed: {', '.join(sorted(known))}")


def _network_options(net: Network, options: Any, preset: Preset) -> Any:
    """``options`` as ``net``'s options dataclass (a mapping read into it; None: the preset's)."""
    if options is None:
        return net.make_options(preset.value)
    if isinstance(options, Mapping):
        unknown = sorted(set(options) - net.option_names())
        if unknown:
            raise ConfigError(f"unknown {net.name} option(s) {', '.join(unknown)}", field="network",
                              hint=f"allowed: {', '.join(sorted(net.option_names()))}")
        return net.options_class()(**options)
    if not isinstance(options, net.options_class()):
        raise ConfigError(f"network options of type {type(options).__name__} for {net.name}", field="network",
                          hint=f"give a {net.options_class().__name__}")
    return options


@dataclass(frozen=True)
class TrainConfig:
    """Every training option, once.

    The defaults train the CPU ``small`` preset on a ``make run``-sized dataset (a few hundred
    1-s windows) in about a minute per method on 2 cores; raise ``max_steps`` for real data.

    Attributes:
        method: Which model to train.
        preset: Network size preset (:class:`Preset`).
        seed: Seed of weights, batch order, noise and timesteps.
        max_steps: Optimiser steps.
        batch_size: Windows per step (global batch; split across processes under torchrun).
        lr: Peak learning rate of AdamW (the released code: 8e-5 at batch 1024).
        weight_decay: AdamW weight decay.
        warmup_steps: Linear warm-up steps of the cosine schedule.
        grad_clip: Gradient-norm clip.
        ema_decay: Maximum decay of the exponential moving average of the weights (diffusion
            models; evaluation uses the EMA weights).
        ema_power: Warm-up power of the EMA decay (diffusion_policy: ``1 - (1 + step)^-power``).
        val_every: Validation (and best-checkpoint choice) every this many steps.
        checkpoint_every: ``last.pt`` every this many steps (and at the end).
        use_temperature: Condition on the IMU temperature as a 7th channel (the dataset must
            carry ``temperature_degc``).
        num_workers: DataLoader worker processes.
        threads: CPU threads of torch in this process (0: torch's default, one per core). Give
            each of several parallel jobs its share of the cores: oversubscribed threads slow
            CPU training down many times.
        device: ``auto`` (CUDA when available), ``cpu``, ``cuda`` or ``cuda:N``.
        val_batches: At most this many validation batches per validation (0: all).
        indirect_weights: Weights of the rotation (rad), velocity (m/s) and position (m) errors
            in the indirect loss.
        model_overrides: Single :class:`ModelConfig` values replacing the preset's.
    """

    method: str = field(default_factory=lambda: network_names()[0])
    preset: Preset = Preset.SMALL
    seed: int = 0
    max_steps: int = 300
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-6
    warmup_steps: int = 100
    grad_clip: float = 1.0
    ema_decay: float = 0.999
    ema_power: float = 0.75
    val_every: int = 50
    checkpoint_every: int = 50
    use_temperature: bool = False
    num_workers: int = 0
    threads: int = 0
    device: str = "auto"
    val_batches: int = 0
    indirect_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    model_overrides: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "method", get_network(self.method).name)
        try:
            object.__setattr__(self, "preset", Preset(self.preset))
        except ValueError:
            raise ConfigError(f"unknown preset '{self.preset}'", field="preset",
                              hint=f"choose one of {', '.join(p.value for p in Preset)}") from None
        object.__setattr__(self, "indirect_weights", tuple(float(w) for w in self.indirect_weights))
        object.__setattr__(self, "model_overrides", dict(self.model_overrides))
        for name in ("max_steps", "batch_size", "val_every", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} is {getattr(self, name)}", field=name, hint="use a positive integer")
        for name in ("warmup_steps", "num_workers", "val_batches", "threads"):
            if int(getattr(self, name)) < 0:
                raise ConfigError(f"{name} is {getattr(self, name)}", field=name, hint="use 0 or more")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ConfigError(f"ema_decay is {self.ema_decay}", field="ema_decay", hint="use a value in [0, 1)")
        if self.lr <= 0 or self.grad_clip <= 0:
            raise ConfigError("lr and grad_clip must be positive", field="lr")
        if len(self.indirect_weights) != 3:
            raise ConfigError("indirect_weights needs 3 values (rotation, velocity, position)",
                              field="indirect_weights")
        self.model_config()  # unknown or invalid overrides fail here, at load time

    def model_config(self) -> ModelConfig:
        """The network sizes this training uses (preset, temperature channel, overrides).

        ``model_overrides`` may name the options of another network (a workflow's options apply to
        every method of its plan): those of this method's network and the shared ones are applied;
        only when others are given are the other networks' options read to check them.
        """
        own = ModelConfig.shared_options() | get_network(self.method).option_names()
        foreign = set(self.model_overrides) - own
        if foreign:
            check_model_overrides(foreign, network_names())
        channels = IMU_CHANNELS + (1 if self.use_temperature else 0)
        return ModelConfig.for_preset(self.method, self.preset, condition_channels=channels,
                                      **{k: v for k, v in self.model_overrides.items() if k in own})

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None, *, path: str | Path | None = None) -> TrainConfig:
        """Build from a plain mapping (YAML), with one-line :class:`ConfigError` naming ``path``."""
        try:
            return dataclass_from_mapping(cls, d, what="training option", field="training")
        except ConfigError as exc:
            if path is None:
                raise
            raise ConfigError(exc.problem, path=path, field=exc.field, hint=exc.hint) from None

    def replace(self, **changes: Any) -> TrainConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)


# ----------------------------------------------------------------------------- workflow sections


class ExportFormat(str, enum.Enum):
    """File format of an exported model."""

    TORCHSCRIPT = "torchscript"
    ONNX = "onnx"


class EvalGravity(str, enum.Enum):
    """Gravity the evaluation integrates every window with."""

    NOMINAL = "nominal"  # pipeline.types.DEFAULT_GRAVITY_MPS2 in the reference world frame (the paper)
    RECOVERED = "recovered"  # each sequence's recovered gravity (the nominal one when it has none)


class OracleWalk(str, enum.Enum):
    """Random-walk strengths of the random-walk oracle."""

    SENSOR = "sensor"  # the sensor's own calibration (EuRoC's imu0/sensor.yaml; the paper)
    RECOVERY = "recovery"  # those each sequence's recovery used


def seeds_error(seeds: Any) -> ConfigError | None:
    """The error of a ``training.seeds`` value that is not a list of non-negative integers (naming every bad
    one), or None."""
    if not isinstance(seeds, (list, tuple)):
        return ConfigError(f"training seeds must be a list, got {seeds!r}", field="training.seeds",
                           hint="e.g. seeds: [0, 1, 2]")
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, int) or s < 0]
    if not bad:
        return None
    return ConfigError(f"training seeds must be non-negative integers, got {', '.join(map(repr, bad))}",
                       field="training.seeds", hint="list whole numbers 0, 1, 2, ... (e.g. seeds: [0, 1, 2])")


@dataclass(frozen=True)
class TrainingPlan:
    """The workflow's ``training:`` section: which runs to train.

    Attributes:
        methods: Learned methods, one job per method and seed.
        seeds: Training seeds (Table I shows mean and spread over seeds).
        preset: Network size preset of every run.
        options: Further :class:`training.config.TrainConfig` options (``max_steps``,
            ``batch_size``, ``lr``, ...; not ``method``, ``seed``, ``preset``).
        processes: Data-parallel processes per training job: more than 1 launches ``biasgt
            train`` under ``torchrun --standalone --nproc-per-node N`` inside the job (one per GPU
            on a GPU node, gloo processes on CPU); the global batch stays ``batch_size``.
        threads: CPU threads of each learning job (``train`` and ``evaluate``; Snakemake's
            ``threads:``, which a profile's ``set-threads`` overrides). The small models do not
            use 2 threads well: on 2 cores, 1 lets two jobs run at once, about 1.7x the
            throughput of one 2-thread job.
    """

    methods: tuple[str, ...] = field(default_factory=lambda: network_names(default_only=True))
    seeds: tuple[int, ...] = field(default=(0,), metadata={"check": seeds_error})
    preset: Preset = Preset.SMALL
    options: Mapping[str, Any] = field(default_factory=dict)
    processes: int = 1
    threads: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", tuple(get_network(m, field="training.methods").name for m in self.methods))
        if (bad := seeds_error(self.seeds)) is not None:
            raise bad
        object.__setattr__(self, "seeds", tuple(self.seeds))
        object.__setattr__(self, "preset", Preset(self.preset))
        object.__setattr__(self, "options", dict(self.options))
        reserved = sorted({"method", "seed", "preset"} & set(self.options))
        if reserved:
            raise ConfigError(f"training.options sets {', '.join(reserved)}", field="training.options",
                              hint="give methods, seeds and preset at the top of the training section")
        if int(self.processes) < 1:
            raise ConfigError(f"training.processes must be >= 1, got {self.processes!r}", field="training.processes",
                              hint="give the number of data-parallel processes per job, e.g. 1 or the GPUs per node")
        object.__setattr__(self, "processes", int(self.processes))
        if int(self.threads) < 1:
            raise ConfigError(f"training.threads must be >= 1, got {self.threads!r}", field="training.threads",
                              hint="give the CPU threads of each train / evaluate job, e.g. 1 or 2")
        object.__setattr__(self, "threads", int(self.threads))
        if len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"training seeds repeat: {list(self.seeds)}", field="training.seeds",
                              hint="list each seed once")
        try:  # the plan's options apply to every method it names: only these networks' options are read
            check_model_overrides(self.model_overrides, self.methods)
        except ConfigError as exc:
            raise ConfigError(exc.problem, field="options.model_overrides", hint=exc.hint) from None
        for m in self.methods:
            self.train_config(m, self.seeds[0] if self.seeds else 0)  # bad options fail at load time

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> TrainingPlan:
        """From the (partial) ``training:`` section; one-line :class:`ConfigError` on bad keys or values."""
        return dataclass_from_mapping(cls, d, what="training option", field="training")

    @property
    def model_overrides(self) -> dict[str, Any]:
        """The plan's ``options.model_overrides`` (every method's; each applies its own)."""
        overrides = self.options.get("model_overrides") or {}
        return dict(overrides) if isinstance(overrides, Mapping) else overrides

    def train_config(self, method: str, seed: int) -> TrainConfig:
        """The :class:`TrainConfig` of one run: the plan's options, with the model options that apply to
        ``method`` (its network's and the shared ones).

        Raises:
            ConfigError: A bad option, its field named within the section (``options.<key>``).
        """
        net = get_network(method)
        options = dict(self.options)
        if isinstance(options.get("model_overrides"), Mapping):
            own = ModelConfig.shared_options() | net.option_names()
            options["model_overrides"] = {k: v for k, v in options["model_overrides"].items() if k in own}
        try:
            return TrainConfig.from_mapping({**options, "method": net.name, "seed": int(seed), "preset": self.preset})
        except ConfigError as exc:  # TrainConfig names its fields as the top of a 'training:' file does
            key = (exc.field or "").removeprefix("training").lstrip(".")
            raise ConfigError(exc.problem, field=f"options.{key}" if key else "options", hint=exc.hint) from None

    def run_settings(self, method: str, seed: int | str) -> dict[str, Any]:
        """Parameters of one train job: its resolved :class:`TrainConfig` as a plain mapping with the plan's
        whole ``model_overrides`` (so that adding a method or a seed retrains nothing else)."""
        settings = self.train_config(method, int(seed)).to_dict()
        if "model_overrides" in self.options:
            settings["model_overrides"] = to_plain(self.model_overrides)
        return settings

    def runs(self) -> list[tuple[str, int]]:
        return [(m, s) for m in self.methods for s in self.seeds]

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)


@dataclass(frozen=True)
class Draw:
    """How one pass of an evaluation draws a predictor's bias: ``samples`` per window with ``sampler`` in
    ``steps`` denoising steps, the noise seeded from ``seed`` (a deterministic predictor: one sample, no
    sampler). :meth:`EvaluationConfig.draws` makes them; the predictor reads them, nothing in between."""

    samples: int
    sampler: Sampler | None
    steps: int
    seed: int
    backend: SamplingBackend = SamplingBackend.EXACT
    rows: int = 2048


@dataclass(frozen=True)
class EvaluationConfig:
    """Options of an evaluation (the workflow's ``evaluation:`` section maps onto it).

    Attributes:
        samples: Samples per window of a diffusion model (K).
        samplers: Samplers of a diffusion model, each evaluated (correct DDIM and the
            released code's, for the ablation).
        steps: Denoising steps of the sampler.
        seed: Seed of the sampling noise and of the oracle's random walks.
        batch_windows: Windows per evaluation batch (their errors are computed together).
        backend: How a diffusion model's denoiser runs (:class:`SamplingBackend`; ``exact``: float32).
        sample_rows: At most this many rows (windows x K samples) per call of a diffusion model's
            sampler; a batch's windows are drawn in chunks of ``sample_rows // K`` (at least one).
            The samples do not depend on it (each window draws its noise from its own generator).
        examples: Test windows kept for the report's figure.
        references: Reference rows evaluated by the workflow (:mod:`training.references`; default:
            the rows registered as default).
        gravity: Gravity of the integration (:class:`EvalGravity`).
        oracle_random_walk: Random-walk strengths of the oracle (:class:`OracleWalk`).
    """

    samples: int = SAMPLES
    samplers: tuple[Sampler, ...] = (Sampler.DDIM, Sampler.RELEASED)
    steps: int = STEPS
    seed: int = 0
    batch_windows: int = 32
    backend: SamplingBackend = SamplingBackend.EXACT
    sample_rows: int = 2048
    examples: int = 4
    references: tuple[str, ...] = field(default_factory=lambda: reference_names(default_only=True))
    gravity: EvalGravity = EvalGravity.RECOVERED
    oracle_random_walk: OracleWalk = OracleWalk.RECOVERY

    def __post_init__(self) -> None:
        for name, kind in (("gravity", EvalGravity), ("oracle_random_walk", OracleWalk), ("backend", SamplingBackend)):
            try:
                object.__setattr__(self, name, kind(getattr(self, name)))
            except ValueError:
                raise ConfigError(f"evaluation {name} {getattr(self, name)!r} is not one of "
                                  f"{[k.value for k in kind]}", field=name,
                                  hint=f"give one of {', '.join(k.value for k in kind)}") from None
        object.__setattr__(self, "samplers", tuple(Sampler(s) for s in self.samplers))
        object.__setattr__(self, "references", tuple(get_reference(b, field="references").name
                                                     for b in self.references))
        for name in ("samples", "steps", "batch_windows", "sample_rows"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"evaluation {name} must be >= 1, got {getattr(self, name)!r}", field=name,
                                  hint=f"give a positive {name}")
        if not self.samplers:
            raise ConfigError("no sampler to evaluate", field="samplers", hint="list at least 'ddim'")

    def draws(self, stochastic: bool) -> tuple[Draw, ...]:
        """The passes of a predictor: one per sampler, ``samples`` each, for a stochastic one (a diffusion
        model); one deterministic pass otherwise."""
        if not stochastic:
            return (Draw(1, None, self.steps, self.seed),)
        return tuple(Draw(self.samples, sampler, self.steps, self.seed, self.backend, self.sample_rows)
                     for sampler in self.samplers)

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> EvaluationConfig:
        """From a (partial) ``evaluation:`` mapping; one-line :class:`ConfigError` on bad keys."""
        return dataclass_from_mapping(cls, d, what="evaluation option", field="evaluation")

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)
