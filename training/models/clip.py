"""The diffusion samplers' x0 clip: its range chosen from evidence, and how often it binds.

:func:`clip_bounds` resolves :attr:`training.config.ModelConfig.clip_x0_range` into raw-unit
bounds per channel at training time (the train and validation splits' biases are the evidence;
the test split is never read). :class:`ClipUse` is what an evaluation reports per sampler: the
bounds and the fraction of sample values that sit on them (their last step's x0 estimate was
clipped) or were clipped at one step or more.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pipeline.errors import DataError
from training.config import IMU_CHANNELS, ClipRange, ModelConfig, Sampler

__all__ = ["ClipUse", "clip_bounds", "clip_use", "largest_deviation"]

Bounds = tuple[tuple[float, ...], tuple[float, ...]]


def largest_deviation(biases: Iterable[np.ndarray], mean: np.ndarray) -> np.ndarray:
    """Per channel, the largest ``|bias - mean|`` over arrays [..., 6] (zeros when there are none)."""
    out = np.zeros(IMU_CHANNELS)
    for b in biases:
        b = np.asarray(b, dtype=np.float64).reshape(-1, IMU_CHANNELS)
        if len(b):
            out = np.maximum(out, np.abs(b - mean).max(axis=0))
    return out


def clip_bounds(config: ModelConfig, bias_mean: Any, bias_std: Any, biases: Iterable[np.ndarray]) -> Bounds | None:
    """The raw-unit ``(lo, hi)`` clip of the x0 estimates (None: no clipping).

    Args:
        config: ``clip_x0_range``, ``clip_x0_sigmas``, ``clip_x0_bias_range``.
        bias_mean: The train split's mean bias [6] (rad/s, m/s^2).
        bias_std: The train split's bias std [6].
        biases: The train and validation splits' bias arrays [..., 6] (read for ``evidence`` only).

    Raises:
        DataError: ``sensor`` range that does not hold the train mean (the range or the labels are wrong).
    """
    if config.clip_x0_sigmas is None:
        return None
    mean, std = np.asarray(bias_mean, dtype=np.float64), np.asarray(bias_std, dtype=np.float64)
    margin = float(config.clip_x0_sigmas) * std
    if config.clip_x0_range is ClipRange.SENSOR:
        r = np.asarray(config.clip_x0_bias_range, dtype=np.float64)
        if np.any(np.abs(mean) >= r):
            raise DataError(f"the train split's mean bias {np.round(mean, 6).tolist()} lies outside clip_x0_bias_range "
                            f"{r.tolist()}", field="clip_x0_bias_range",
                            hint="give the sensor's stated bias range (rad/s, m/s^2), or clip_x0_range: evidence")
        lo, hi = -r, r
    elif config.clip_x0_range is ClipRange.TRAIN:
        lo, hi = mean - margin, mean + margin
    else:
        half = largest_deviation(biases, mean) + margin
        lo, hi = mean - half, mean + half
    return tuple(map(float, lo)), tuple(map(float, hi))


@dataclass(frozen=True)
class ClipUse:
    """How often one sampler's clip bound during an evaluation, per channel.

    Attributes:
        sampler: The sampler (``ddim``, ``ddpm`` or ``released``).
        lo / hi: The clip range in raw units (rad/s, m/s^2), 6 values each.
        on_bound: Fraction of the sample values (samples x windows x time steps) clipped at the
            last step, i.e. sitting on a bound: values the clip kept from going further.
        any_step: Fraction clipped at one step or more.
    """

    sampler: str
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    on_bound: tuple[float, ...]
    any_step: tuple[float, ...]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ClipUse:
        return cls(str(d["sampler"]), *(tuple(float(v) for v in d[k]) for k in ("lo", "hi", "on_bound", "any_step")))


def clip_use(model: Any, sampler: Sampler, count: Any) -> ClipUse:
    """The :class:`ClipUse` of ``sampler`` from a model (:class:`training.models.BiasModel`) and the
    :class:`training.models.scheduler.ClipCount` of its sampling runs (NaN bounds: no clipping)."""
    bounds = model.released_clip() if sampler is Sampler.RELEASED else model.x0_clip()
    nz = model.normalizer
    if bounds is None:
        lo = hi = torch.full((IMU_CHANNELS,), float("nan"))
    else:
        if not isinstance(bounds, tuple):
            bounds = (torch.full((IMU_CHANNELS,), -bounds), torch.full((IMU_CHANNELS,), bounds))
        lo, hi = (nz.unbias(b.to(nz.bias_mean)) for b in bounds)
    on_bound, any_step = count.fractions()
    return ClipUse(Sampler(sampler).value, tuple(lo.double().tolist()), tuple(hi.double().tolist()),
                   tuple(on_bound), tuple(any_step))
