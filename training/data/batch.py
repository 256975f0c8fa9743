"""``WindowBatch``: a typed batch of training windows (what every model and loss reads)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import torch

from pipeline.errors import DataError

__all__ = ["WindowBatch", "TEMPERATURE_KEY"]

#: Name of the optional per-sample IMU temperature in dataset items and batches ([T], deg C).
TEMPERATURE_KEY = "temperature_degc"


@dataclass
class WindowBatch:
    """B windows of T samples, raw units.

    Attributes:
        imu: [B, T, 6] gyro (rad/s) then acc (m/s^2).
        bias: [B, T, 6] ground-truth (recovered) bias, same order and units.
        bias_std: [B, T, 6] its standard deviation.
        dt_s: [B, T-1] sample intervals (s).
        start_R, start_v, start_p: [B, 3, 3] world-from-imu, [B, 3] (m/s), [B, 3] (m) reference
            state at the first sample.
        end_R, end_v, end_p: The same at the last sample.
        temperature_degc: [B, T] IMU temperature (deg C) when the dataset carries it, else None.
        gravity_mps2: [B, 3] gravity in the reference world frame when known (the indirect loss
            integrates with it), else None (the loss uses the validation's default).
        context: [B, F] each window's context from its sequence's record (:class:`training.context.model.ContextFeeder`), for a network
            that reads one (:attr:`training.networks.Network.context`), else None.
    """

    imu: torch.Tensor
    bias: torch.Tensor
    bias_std: torch.Tensor
    dt_s: torch.Tensor
    start_R: torch.Tensor
    start_v: torch.Tensor
    start_p: torch.Tensor
    end_R: torch.Tensor
    end_v: torch.Tensor
    end_p: torch.Tensor
    temperature_degc: torch.Tensor | None = None
    gravity_mps2: torch.Tensor | None = None
    context: torch.Tensor | None = None

    @classmethod
    def from_items(cls, items: Mapping[str, Any]) -> WindowBatch:
        """From a :class:`training.data.dataset.WindowDataset` ``DataLoader`` batch (a dict of stacked
        tensors; ``t0_ns`` and ``sequence`` are ignored).

        Raises:
            DataError: A required array is missing.
        """
        names = [f.name for f in fields(cls) if f.name not in (TEMPERATURE_KEY, "gravity_mps2", "context")]
        missing = [n for n in names if n not in items]
        if missing:
            raise DataError(f"window batch lacks {missing}", hint="load windows with training.data.dataset.WindowDataset")
        return cls(**{n: items[n] for n in names}, temperature_degc=items.get(TEMPERATURE_KEY),
                   gravity_mps2=items.get("gravity_mps2"), context=items.get("context"))

    def to(self, device: torch.device | str) -> WindowBatch:
        """The batch on ``device`` (tensors moved, None kept)."""
        return replace(self, **{f.name: getattr(self, f.name).to(device) for f in fields(self)
                                if getattr(self, f.name) is not None})

    def __len__(self) -> int:
        return int(self.imu.shape[0])

    def rows(self, start: int, stop: int) -> WindowBatch:
        """Windows ``start .. stop-1`` (views of the tensors, None kept)."""
        return replace(self, **{f.name: getattr(self, f.name)[start:stop] for f in fields(self)
                                if getattr(self, f.name) is not None})

    def condition(self, use_temperature: bool) -> torch.Tensor:
        """The raw condition input [B, T, 6] (or [B, T, 7] with the temperature last).

        Raises:
            DataError: ``use_temperature`` and the batch has no temperature.
        """
        if not use_temperature:
            return self.imu
        if self.temperature_degc is None:
            raise DataError("the model conditions on temperature but the windows carry no 'temperature_degc'",
                            hint="re-create the dataset from sequences with IMU temperature, or train with "
                                 "use_temperature: false")
        return torch.cat([self.imu, self.temperature_degc.to(self.imu.dtype).unsqueeze(-1)], dim=-1)
