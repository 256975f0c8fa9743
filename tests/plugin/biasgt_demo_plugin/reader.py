"""An IMU logger's CSV: ``t_ms,gx,gy,gz,ax_g,ay_g,az_g`` (stamps in ms, gyro in rad/s, acc in g)."""

from pathlib import Path

import numpy as np

from pipeline.types import ImuSeries, Sequence

HEADER = "t_ms,gx,gy,gz,ax_g,ay_g,az_g"
G0 = 9.80665  # standard gravity [m/s^2]: 1 g


def detect(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open(encoding="utf-8", errors="replace") as f:
        return f.readline().strip() == HEADER


def load(path: Path, *, name: str | None = None) -> Sequence:
    rows = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    imu = ImuSeries(np.round(rows[:, 0] * 1e6).astype(np.int64), rows[:, 1:4], rows[:, 4:7] * G0)
    return Sequence(name=name or path.stem, imu=imu)
