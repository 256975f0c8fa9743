"""Options of the interpolation stage (one source: the CLI, the workflow schema and the steps read them here)."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class InterpolationMethod(str, enum.Enum):
    """How bias is interpolated between keyframes."""

    LINEAR = "linear"  # Brownian-bridge mean (default)
    CUBIC = "cubic"  # Akima spline through the keyframes


@dataclass(frozen=True)
class InterpolationConfig:
    """Options of ``biasgt interpolate`` and of the workflow's ``interpolation:`` section.

    Attributes:
        method: Interpolation of the mean.
        clamp: Hold the end values beyond the recovered span (the rows are flagged and their sigma
            grows with the random walk) instead of refusing: the IMU usually starts before and ends
            after the poses.
        write_csv: With a ``.parquet`` output, also write the same table as CSV next to it.
    """

    method: InterpolationMethod = InterpolationMethod.LINEAR
    clamp: bool = True
    write_csv: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "method", InterpolationMethod(self.method))
