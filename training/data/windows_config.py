"""Options of the windows stage: one source for ``biasgt windows`` and the workflow's ``windows:`` section."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.configs import dataclass_from_mapping, dataclass_to_mapping
from pipeline.errors import ConfigError
from validation.config import ValidationConfig


@dataclass(frozen=True)
class WindowConfig:
    """How sequences are cut into windows.

    Attributes:
        window_s: Window length in seconds (``n = round(window_s * rate)`` intervals, n + 1 samples).
        overlap: Fraction of a window shared with the next, in [0, 1) (0.5: stride window_s / 2).
        resample_hz: Resample IMU streams onto a uniform grid at this rate (Hz) where needed;
            None refuses sequences at another rate (see the module docstring).
        gap_factor: An IMU interval longer than this times the nominal one is a gap.
        accept_warn: Take sequences whose validation verdict is WARN too (PASS always, FAIL never;
            a sequence without a validation is taken, and the manifest says it was not validated).
    """

    window_s: float = 1.0
    overlap: float = 0.5
    resample_hz: float | None = None
    gap_factor: float = 2.0
    accept_warn: bool = False

    def __post_init__(self) -> None:
        try:
            for name in ("window_s", "overlap", "gap_factor"):
                object.__setattr__(self, name, float(getattr(self, name)))
            if self.resample_hz is not None:
                object.__setattr__(self, "resample_hz", float(self.resample_hz))
        except (TypeError, ValueError):
            raise ConfigError(f"window settings must be numbers, got {self.__dict__}",
                              hint="give window_s, overlap, gap_factor (and resample_hz) as numbers") from None
        checks = (
            ("window_s", np.isfinite(self.window_s) and self.window_s > 0, "give a positive length in seconds"),
            ("overlap", 0.0 <= self.overlap < 1.0, "give an overlap in [0, 1), e.g. 0.5"),
            ("resample_hz", self.resample_hz is None or (np.isfinite(self.resample_hz) and self.resample_hz > 0),
             "give a positive rate in Hz, e.g. 200"),
            ("gap_factor", self.gap_factor > 1.0, "give a factor > 1, e.g. 2"),
        )
        for name, ok, hint in checks:
            if not ok:
                raise ConfigError(f"invalid window setting {name} = {getattr(self, name)!r}", field=name, hint=hint)

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> WindowConfig:
        """Build from a (possibly partial) mapping (:func:`pipeline.configs.dataclass_from_mapping`)."""
        return dataclass_from_mapping(cls, d, what="window setting", field="windows")

    def validation_config(self) -> ValidationConfig:
        """The validation config that cuts the same windows."""
        return ValidationConfig(window_s=self.window_s, overlap=self.overlap, gap_factor=self.gap_factor)
