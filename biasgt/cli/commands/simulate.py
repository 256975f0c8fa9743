"""``biasgt simulate``: write a synthetic sequence with exactly known bias (thin adapter over pipeline.sim)."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

import yaml

from pipeline.files.atomic import OutputKind
from pipeline.sim.config import MotionPreset, PoseFormat, SimConfig

log = logging.getLogger(__name__)

DESCRIPTION = """\
Simulate an IMU + pose recording whose true bias, clock offset and extrinsic are known exactly,
and write it as a EuRoC/ASL folder that every biasgt reader accepts:

  OUT/mav0/imu0/data.csv                          IMU (integer ns, full-precision values)
  OUT/mav0/imu0/sensor.yaml                       reported (datasheet) noise values
  OUT/mav0/mocap0/ | leica0/ | OUT/vio_tum.txt    the pose stream (per --pose-format)
  OUT/mav0/state_groundtruth_estimate0/data.csv   TRUE state incl. the true bias at IMU rate
  OUT/simulation.yaml                             resolved config, seed and the truth

Motion is a smooth random trajectory (--preset) or, with --ground-truth, the motion AND the bias
of a real EuRoC ground-truth state file ("semi-real"); a TUM pose file there gives the motion
only, and the bias is then drawn from the IMU model (labelled 'bias_source: simulated'). The same seed gives byte-identical files.
Options override the --config file; the config file holds every knob (see pipeline/sim/config.py).
"""

EPILOG = """\
examples:
  biasgt simulate out/sim01 --duration 120 --seed 1
  biasgt simulate out/drone --preset aggressive_drone --clock-offset-ms 12.5 --extrinsic-deg 5 --extrinsic-m 0.08
  biasgt simulate out/leica --pose-format position --pose-rate 20 --dropouts 3 --outliers 5
  biasgt simulate out/semi --ground-truth data/V1_02_medium/mav0/state_groundtruth_estimate0/data.csv
"""


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="write a synthetic sequence with exactly known bias (EuRoC/ASL folder)",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("out", metavar="OUT", type=Path, help="output folder (replaced atomically if it exists)")
    p.add_argument("--config", metavar="FILE.yaml", type=Path, help="simulation config (a partial SimConfig as YAML)")
    p.add_argument(
        "--duration", metavar="S", type=float, help="seconds of IMU data (default 60; with --ground-truth: whole file)"
    )
    p.add_argument("--seed", metavar="N", type=int, help="random seed (default 0)")
    p.add_argument("--name", help="sequence name (default 'sim')")
    p.add_argument(
        "--preset", choices=[m.value for m in MotionPreset],
        help="kind of random motion (median speed, rate): handheld (0.6 m/s, 0.5 rad/s), aggressive_drone "
        "(3 m/s, 1.4 rad/s), slow_cart (0.5 m/s, 0.08 rad/s, nearly level); default handheld",
    )
    p.add_argument(
        "--pose-format", choices=[f.value for f in PoseFormat],
        help="mocap: 6-DoF mav0/mocap0; position: position-only mav0/leica0 (Leica-like); "
        "vio: drifting odometry as vio_tum.txt (default mocap)",
    )
    p.add_argument("--pose-rate", metavar="HZ", type=float, help="pose rate (default 100)")
    p.add_argument(
        "--clock-offset-ms", metavar="X", type=float,
        help="pose clock offset: t_imu = pose_stamp + X ms (the recovery's pose_time_offset_s; default 0)",
    )
    p.add_argument(
        "--extrinsic-deg", metavar="A", type=float, help="rotation angle of T_imu_<tracked frame> about a random axis"
    )
    p.add_argument("--extrinsic-m", metavar="D", type=float, help="length of the IMU-to-tracked-frame lever arm")
    p.add_argument("--extrinsic-known", action="store_true", help="write the extrinsic as T_BS in the pose sensor.yaml")
    p.add_argument("--dropouts", metavar="N", type=int, help="number of gaps in the pose stream")
    p.add_argument("--outliers", metavar="N", type=int, help="number of pose samples displaced by 10 cm")
    p.add_argument("--noise-free", action="store_true", help="no IMU white noise and no pose noise (bias is kept)")
    p.add_argument(
        "--ground-truth", metavar="FILE", type=Path,
        help="EuRoC state_groundtruth_estimate0/data.csv: take the motion AND the bias from it (semi-real); "
             "a TUM pose file of the IMU: the motion only (the bias is simulated)",
    )
    p.add_argument("--bag", choices=["ros1", "ros2"], help="also write a ROS1 sim.bag or ROS2 sim_ros2/ bag")
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def build_config(args: argparse.Namespace) -> SimConfig:
    """The :class:`SimConfig` of a parsed command line (config file, then the options)."""
    base = SimConfig.from_yaml(args.config) if args.config is not None else SimConfig()
    d = base.to_dict()
    top = {"duration": "duration_s", "seed": "seed", "name": "name"}
    for opt, key in top.items():
        if getattr(args, opt) is not None:
            d[key] = getattr(args, opt)
    if args.preset is not None:
        d["motion"]["preset"] = args.preset
    if args.ground_truth is not None:
        d["motion"]["ground_truth_path"] = str(args.ground_truth)
        if args.duration is None and (args.config is None or "duration_s" not in _raw_keys(args.config)):
            d["duration_s"] = None
    poses = d["poses"]
    for opt, key, scale in (
        ("pose_format", "format", None),
        ("pose_rate", "rate_hz", None),
        ("clock_offset_ms", "clock_offset_s", 1e-3),
        ("extrinsic_deg", "extrinsic_rotation_deg", None),
        ("extrinsic_m", "extrinsic_translation_m", None),
        ("dropouts", "dropouts", None),
        ("outliers", "outliers", None),
    ):
        value = getattr(args, opt)
        if value is not None:
            poses[key] = value * scale if scale is not None else value
    if args.extrinsic_known:
        poses["extrinsic_known"] = True
    config = SimConfig.from_dict(d, path=args.config)
    return config.noise_free() if args.noise_free else config


def _raw_keys(path: Path) -> set[str]:
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    return set(data) if isinstance(data, dict) else set()


def run(args: argparse.Namespace) -> int:
    from pipeline.sim.simulator import simulate  # scipy.signal: off the CLI start-up path
    from pipeline.sim.writer import write_simulation  # rosbags: off the CLI start-up path

    config = build_config(args)
    t0 = time.perf_counter()
    sim = simulate(config)
    log.info(
        "simulated %.1f s (%d IMU samples, %d poses) in %.2f s",
        sim.config.duration_s, len(sim.sequence.imu), len(next(iter(sim.sequence.poses.values()))),
        time.perf_counter() - t0,
    )
    out = write_simulation(sim, args.out, bag=args.bag)
    print(out)
    return 0


__all__ = ["build_config", "register", "run"]
