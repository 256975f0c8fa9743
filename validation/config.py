"""Options of the validation stage: one source for the CLI, the workflow's ``validation:`` section
and the windows stage (which cuts the same windows)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

from pipeline.configs import dataclass_to_mapping
from pipeline.errors import ValidationError
from pipeline.types import IntegrationScheme


class CrossvalMode(str, enum.Enum):
    """When the recovered bias is cross-validated by time blocks (:mod:`validation.crossval.blocks`).

    AUTO: when the reference is the pose stream the bias was fitted to: those poses cannot show what
        the bias absorbed from them, the held-out blocks can (and then judge the verdict).
    ON: always (against an independent reference the held-out bias is compared, not judged).
    OFF: never.
    """

    AUTO = "auto"
    ON = "on"
    OFF = "off"


class BiasSourceKind(str, enum.Enum):
    """What a bias source is (decides its role in the verdict; :mod:`validation.sources`)."""

    ZERO = "zero"
    CONSTANT_FIRST_WINDOW = "constant_first_window"
    DATASET = "dataset"
    RECOVERED = "recovered"
    FILE = "file"


@dataclass(frozen=True)
class ValidationConfig:
    """Knobs of the validation (every default is documented in the module docstring).

    Attributes:
        window_s: Window length (s).
        overlap: Fraction of a window shared with the next, in [0, 1) (0.5: stride window_s/2).
        gap_factor: An IMU interval longer than this times the nominal one is a gap.
        flag_k: A window is flagged above ``flag_k`` x the source's median error.
        flag_min_pos_m / flag_min_rot_deg: Floors of the flag thresholds.
        margin: Relative margin of the FAIL rule (0.10 = 10 %).
        tie_prmse_m / tie_roe_deg: Differences below these count as equal.
        warn_flagged_fraction: WARN above this fraction of flagged candidate windows.
        warn_dropped_fraction: WARN above this fraction of dropped windows.
        chunk_windows: Windows per batched integration call.
        scheme: Integration scheme (MIDPOINT, second order).
        include_zero / include_constant / include_dataset: Add these sources automatically.
        velocity_cutoff_hz: Smoothing-spline cutoff of a POSES reference (None: automatic).
        reference_gap_factor: A reference interval longer than this times its median one is a gap.
        significance: One-sided level of the paired test that makes "worse" a FAIL.
        sigma_k: How many of its own sigmas the candidate may be off before it counts as worse.
        max_random_walk_scale: A recovery whose bias random walk is more than this times (or less
            than 1/this of) the calibration's is only good for WARN.
        crossval: See :class:`CrossvalMode`.
        crossval_block_s: Cross-validation by time blocks of this length (:mod:`validation.crossval.blocks`):
            recover again, with the recovery's own options, without the poses of each fold of blocks;
            the spliced held-out bias is the source ``recovered_heldout``. ``None``: off.
        crossval_folds: Number of folds of that cross-validation (block ``b`` is in fold ``b % folds``).
    """

    window_s: float = 1.0
    overlap: float = 0.5
    gap_factor: float = 2.0
    flag_k: float = 5.0
    flag_min_pos_m: float = 1e-3
    flag_min_rot_deg: float = 1e-2
    margin: float = 0.10
    tie_prmse_m: float = 1e-4
    tie_roe_deg: float = 1e-3
    warn_flagged_fraction: float = 0.05
    warn_dropped_fraction: float = 0.20
    chunk_windows: int = 2048
    scheme: IntegrationScheme = IntegrationScheme.MIDPOINT
    include_zero: bool = True
    include_constant: bool = True
    include_dataset: bool = True
    velocity_cutoff_hz: float | None = None
    reference_gap_factor: float = 4.0
    significance: float = 0.01
    sigma_k: float = 2.0
    max_random_walk_scale: float = 30.0
    crossval: CrossvalMode = CrossvalMode.AUTO
    crossval_block_s: float | None = 10.0
    crossval_folds: int = 3

    def __post_init__(self) -> None:
        object.__setattr__(self, "scheme", IntegrationScheme(self.scheme))
        try:
            object.__setattr__(self, "crossval", CrossvalMode(self.crossval))
        except ValueError:
            raise ValidationError(f"invalid crossval = {self.crossval!r}", field="crossval",
                                  hint="use one of " + ", ".join(m.value for m in CrossvalMode)) from None
        checks = (
            ("window_s", self.window_s > 0, "give a positive window length in seconds"),
            ("overlap", 0.0 <= self.overlap < 1.0, "give an overlap in [0, 1), e.g. 0.5"),
            ("gap_factor", self.gap_factor > 1.0, "give a factor > 1, e.g. 2"),
            ("flag_k", self.flag_k > 1.0, "give a factor > 1, e.g. 5"),
            ("margin", self.margin >= 0.0, "give a relative margin >= 0, e.g. 0.1"),
            ("chunk_windows", self.chunk_windows >= 1, "give a positive number of windows"),
            ("velocity_cutoff_hz", self.velocity_cutoff_hz is None or self.velocity_cutoff_hz > 0,
             "give a positive frequency (Hz) or None for the automatic choice"),
            ("reference_gap_factor", self.reference_gap_factor > 1.0, "give a factor > 1, e.g. 4"),
            ("significance", 0.0 < self.significance < 0.5, "give a test level in (0, 0.5), e.g. 0.01"),
            ("sigma_k", self.sigma_k >= 0.0, "give a number of sigmas >= 0, e.g. 2"),
            ("max_random_walk_scale", self.max_random_walk_scale > 1.0, "give a factor > 1, e.g. 30"),
            ("crossval_block_s", self.crossval_block_s is None or self.crossval_block_s > 0,
             "give a block length in seconds (e.g. 10) or None for no cross-validation"),
            ("crossval_folds", self.crossval_folds >= 2, "give at least 2 folds, e.g. 3"),
        )
        for name, ok, hint in checks:
            if not ok:
                raise ValidationError(f"invalid {name} = {getattr(self, name)!r}", field=name, hint=hint)

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)
