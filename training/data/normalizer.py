"""Per-channel normalisation of IMU readings and bias, stored inside the model's ``state_dict``.

The statistics are the window dataset's train-split statistics (``manifest.json``
``normalization``: ``imu_mean``, ``imu_std``, ``bias_mean``, ``bias_std``, 6 floats each, see
:func:`training.data.dataset.normalization_stats`). As in diffusion_policy's ``LinearNormalizer`` they
are registered buffers of a submodule, so a checkpoint rebuilds the model with its normaliser and
never needs the dataset again.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from pipeline.errors import InputFormatError
from training.config import IMU_CHANNELS

__all__ = ["Normalizer", "STAT_KEYS"]

STAT_KEYS = ("imu_mean", "imu_std", "bias_mean", "bias_std")

#: Smallest standard deviation divided by (a constant channel maps to 0, not to inf).
_MIN_STD = 1e-9


class Normalizer(torch.nn.Module):
    """``(x - mean) / std`` per channel for IMU [.., 6] and bias [.., 6] tensors.

    Args:
        stats: ``STAT_KEYS`` -> 6 floats (gyro x, y, z in rad/s, then acc x, y, z in m/s^2).
        temperature_degc: Mean and std of the IMU temperature (deg C; models conditioned on it).
        path: The file the stats came from, named in errors.

    Raises:
        InputFormatError: A statistic is missing, has another length or is not finite/positive.
    """

    def __init__(self, stats: Mapping[str, Any], *, path: str | Path | None = None,
                 temperature_degc: tuple[float, float] = (0.0, 1.0)) -> None:
        super().__init__()
        for key in STAT_KEYS:
            value = stats.get(key) if isinstance(stats, Mapping) else None
            t = None if value is None else torch.as_tensor(value, dtype=torch.float64).reshape(-1)
            if t is None or t.numel() != IMU_CHANNELS or not torch.isfinite(t).all():
                raise InputFormatError(f"normaliser statistic '{key}' is missing or not {IMU_CHANNELS} finite numbers",
                                       path=path, field=f"normalization.{key}",
                                       hint="re-create the dataset with 'biasgt windows' (it stores them)")
            if key.endswith("_std"):
                if (t < 0).any():
                    raise InputFormatError(f"normaliser statistic '{key}' is negative", path=path,
                                           field=f"normalization.{key}",
                                           hint="re-create the dataset with 'biasgt windows'")
                t = t.clamp_min(_MIN_STD)
            self.register_buffer(key, t.to(torch.float32))
        mean, std = (float(v) for v in temperature_degc)
        self.register_buffer("temperature_mean", torch.tensor(mean, dtype=torch.float32))
        self.register_buffer("temperature_std", torch.tensor(max(std, _MIN_STD), dtype=torch.float32))

    @classmethod
    def from_manifest(cls, manifest: Mapping[str, Any], *, path: str | Path | None = None,
                      temperature_degc: tuple[float, float] = (0.0, 1.0)) -> Normalizer:
        """From a dataset manifest's ``normalization`` entry."""
        stats = manifest.get("normalization")
        if not isinstance(stats, Mapping):
            raise InputFormatError("the dataset has no normaliser statistics", path=path, field="normalization",
                                   hint="re-create the dataset with 'biasgt windows' (it stores them)")
        return cls(stats, path=path, temperature_degc=temperature_degc)

    def stats(self) -> dict[str, list[float]]:
        """The statistics as plain lists (JSON / checkpoint metadata)."""
        out = {k: getattr(self, k).double().tolist() for k in STAT_KEYS}
        out["temperature_degc"] = [float(self.temperature_mean), float(self.temperature_std)]
        return out

    def imu(self, imu: torch.Tensor) -> torch.Tensor:
        """Normalised IMU readings, same shape as ``imu`` [..., 6]."""
        return (imu - self.imu_mean) / self.imu_std

    def condition(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised condition input: IMU [..., 6], or IMU plus temperature last [..., 7]."""
        z = self.imu(x[..., :6])
        if x.shape[-1] == 6:
            return z
        t = (x[..., 6:] - self.temperature_mean) / self.temperature_std
        return torch.cat([z, t], dim=-1)

    def bias(self, bias: torch.Tensor) -> torch.Tensor:
        """Normalised bias, same shape as ``bias`` [..., 6]."""
        return (bias - self.bias_mean) / self.bias_std

    def unbias(self, z: torch.Tensor) -> torch.Tensor:
        """Raw-unit bias (rad/s, m/s^2) from normalised ``z`` [..., 6]."""
        return z * self.bias_std + self.bias_mean
