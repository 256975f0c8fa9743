"""IMU white-noise densities from a recording's rest, when no calibration file gives them.

Where the recording holds stretches at rest (:func:`recovery.calibration_init.find_static_segments`,
together at least ``min_rest_s``), the white-noise densities are read off their Allan deviation
(:func:`recovery.allan.imu_allan`: the slope -1/2 line at tau = 1 s), one value per sensor (the
RMS over its three axes, as a Kalibr ``sensor.yaml`` holds one). The recovery then starts from
these instead of the EuRoC datasheet's (``recovery.json`` ``noise_from_data``), and
:func:`recovery.outputs.suggested_sensor_yaml` writes a ready Kalibr-style ``sensor.yaml`` beside the recovery: these
densities and the random walks the evidence search chose, each with a comment on where it came
from. Units: rad/s/sqrt(Hz), m/s^2/sqrt(Hz) (densities), rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz) (walks).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.errors import BiasgtError
from pipeline.types import ImuSeries, Sequence
from recovery.allan import imu_allan
from recovery.outputs import SENSOR_YAML

log = logging.getLogger(__name__)

#: Least total time at rest for the densities to be read from the data (s).
MIN_REST_S = 10.0
#: Shortest stretch at rest used (s).
MIN_STRETCH_S = 3.0
DENSITY_FIELDS = ("gyro_noise_density", "acc_noise_density")


@dataclass(frozen=True)
class DataNoise:
    """White-noise densities read off a recording's rest.

    Attributes:
        gyro_noise_density: rad/s/sqrt(Hz), RMS over the three axes.
        acc_noise_density: m/s^2/sqrt(Hz), RMS over the three axes.
        gyro_per_axis / acc_per_axis: The per-axis values, [3].
        rest_s: Seconds at rest used; ``stretches``: how many stretches.
        rate_hz: The IMU rate the Allan deviation assumed.
    """

    gyro_noise_density: float
    acc_noise_density: float
    gyro_per_axis: tuple[float, float, float]
    acc_per_axis: tuple[float, float, float]
    rest_s: float
    stretches: int
    rate_hz: float

    def to_dict(self) -> dict[str, Any]:
        return {"gyro_noise_density": self.gyro_noise_density, "acc_noise_density": self.acc_noise_density,
                "gyro_noise_density_per_axis": list(self.gyro_per_axis),
                "acc_noise_density_per_axis": list(self.acc_per_axis), "rest_s": self.rest_s,
                "rest_stretches": self.stretches, "rate_hz": self.rate_hz, "method": "allan_deviation_at_rest",
                "file": SENSOR_YAML}


def densities_from_rest(imu: ImuSeries, *, min_rest_s: float = MIN_REST_S) -> DataNoise | None:
    """The white-noise densities of ``imu`` from its stretches at rest; None without enough rest."""
    try:
        allan = imu_allan(imu, min_static_s=MIN_STRETCH_S, min_total_static_s=min_rest_s)
    except BiasgtError as exc:
        log.info("no noise densities from the data: %s", exc)
        return None
    gyro, acc = np.asarray(allan.gyro_white, float), np.asarray(allan.acc_white, float)
    if not allan.static or not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(acc))):
        return None
    g_rms, a_rms = float(np.sqrt(np.mean(gyro**2))), float(np.sqrt(np.mean(acc**2)))
    log.info("IMU noise densities from %.1f s at rest: gyro %.3g rad/s/sqrt(Hz), acc %.3g m/s^2/sqrt(Hz) (RMS of "
             "the axes)", allan.used_s, g_rms, a_rms)
    return DataNoise(g_rms, a_rms, tuple(float(x) for x in gyro), tuple(float(x) for x in acc),  # type: ignore[arg-type]
                     float(allan.used_s), len(allan.segments_s), float(allan.rate_hz))


def data_noise_for(sequence: Sequence, config_overrides: Mapping[str, float | None]) -> DataNoise | None:
    """:func:`densities_from_rest` when neither a calibration file nor the recovery config gives the
    densities (``config_overrides``: field -> the config's value or None), else None."""
    defaulted = set(sequence.calibration.defaulted())
    if sequence.imu is None or not all(f in defaulted and config_overrides.get(f) is None for f in DENSITY_FIELDS):
        return None
    return densities_from_rest(sequence.imu)
