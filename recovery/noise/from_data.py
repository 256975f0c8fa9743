"""IMU white-noise densities from a recording's rest, when no calibration file gives them.

Where the recording holds stretches at rest (:func:`recovery.calibration_init.find_static_segments`,
together at least ``min_rest_s``), the white-noise densities are read off their Allan deviation
(:func:`recovery.noise.allan.imu_allan`: the slope -1/2 line at tau = 1 s), one value per sensor (the
RMS over its three axes, as a Kalibr ``sensor.yaml`` holds one). The recovery then starts from
these instead of the EuRoC datasheet's (``recovery.json`` ``noise_from_data``), and
:func:`recovery.outputs.suggested_sensor_yaml` writes a ready Kalibr-style ``sensor.yaml`` beside the recovery: these
densities and the random walks the evidence search chose, each with a comment on where it came
from. Units: rad/s/sqrt(Hz), m/s^2/sqrt(Hz) (densities), rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz) (walks).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pipeline.errors import BiasgtError
from pipeline.types import NOISE_DENSITY_FIELDS, ImuNoiseModel, ImuSeries, Sequence
from recovery.noise.allan import imu_allan
from recovery.outputs import SENSOR_YAML

log = logging.getLogger(__name__)

#: Least total time at rest for the densities to be read from the data (s).
MIN_REST_S = 10.0
#: Shortest stretch at rest used (s).
MIN_STRETCH_S = 3.0


@dataclass(frozen=True)
class DataNoise:
    """White-noise densities read off a recording's rest, per axis.

    Attributes:
        gyro_per_axis: rad/s/sqrt(Hz), [3].
        acc_per_axis: m/s^2/sqrt(Hz), [3].
        rest_s: Seconds at rest used; ``stretches``: how many stretches.
        rate_hz: The IMU rate the Allan deviation assumed.
    """

    gyro_per_axis: tuple[float, float, float]
    acc_per_axis: tuple[float, float, float]
    rest_s: float
    stretches: int
    rate_hz: float

    def densities(self) -> dict[str, float]:
        """One value per sensor, the RMS over its three axes (as a Kalibr ``sensor.yaml`` holds one), by
        :data:`~pipeline.types.NOISE_DENSITY_FIELDS` name."""
        return {name: float(np.sqrt(np.mean(np.square(axes))))
                for name, axes in zip(NOISE_DENSITY_FIELDS, (self.gyro_per_axis, self.acc_per_axis))}

    def applied_to(self, noise: ImuNoiseModel) -> ImuNoiseModel:
        """``noise`` (or a subclass) with its white-noise densities replaced by these."""
        return replace(noise, **self.densities())

    def to_dict(self) -> dict[str, Any]:
        per_axis = {f"{name}_per_axis": list(axes)
                    for name, axes in zip(NOISE_DENSITY_FIELDS, (self.gyro_per_axis, self.acc_per_axis))}
        return {**self.densities(), **per_axis, "rest_s": self.rest_s, "rest_stretches": self.stretches,
                "rate_hz": self.rate_hz, "method": "allan_deviation_at_rest", "file": SENSOR_YAML}


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
    found = DataNoise(tuple(float(x) for x in gyro), tuple(float(x) for x in acc),  # type: ignore[arg-type]
                      float(allan.used_s), len(allan.segments_s), float(allan.rate_hz))
    log.info("IMU noise densities from %.1f s at rest (RMS of the axes): %s", allan.used_s,
             ", ".join(f"{k} {v:.3g}" for k, v in found.densities().items()))
    return found


def data_noise_for(sequence: Sequence, config_overrides: Mapping[str, float | None]) -> DataNoise | None:
    """:func:`densities_from_rest` when neither a calibration file nor the recovery config gives the
    densities (``config_overrides``: field -> the config's value or None), else None."""
    defaulted = set(sequence.calibration.defaulted())
    if sequence.imu is None or not all(f in defaulted and config_overrides.get(f) is None
                                       for f in NOISE_DENSITY_FIELDS):
        return None
    return densities_from_rest(sequence.imu)
