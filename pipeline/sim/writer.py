"""Write a :class:`~pipeline.sim.Simulation` as a EuRoC/ASL folder (plus ``simulation.yaml``).

Layout (written atomically; an existing folder is replaced only on success)::

    OUT/
      mav0/imu0/data.csv                        EuRoC IMU CSV, integer ns, full-precision values, plus
                                                the die temperature as a last 'temperature [degC]'
                                                column (see pipeline.io.asl)
      mav0/imu0/sensor.yaml                     T_BS = I and the REPORTED (datasheet) noise values
      mav0/mocap0/data.csv + sensor.yaml        pose format MOCAP (T_BS only if the extrinsic is known)
      mav0/leica0/data.csv + sensor.yaml        pose format POSITION (T_BS lever arm only if known)
      vio_tum.txt                               pose format VIO (TUM text via pipeline.io.tum.write_tum)
      mav0/state_groundtruth_estimate0/data.csv the TRUE state at IMU rate, incl. the true bias
      simulation.yaml                           resolved config, seed and the truth
      sim.bag | sim_ros2/                       optional ROS1 / ROS2 bag of the same IMU + poses

Floats are written with Python's shortest round-trip ``repr`` (full float64 precision), so the
files are byte-identical for the same seed and reading them back is lossless.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.files.atomic import atomic_dir
from pipeline.errors import ConfigError
from pipeline.io.tum import write_tum
from pipeline.sim.config import PoseFormat
from pipeline.sim.simulator import Simulation
from pipeline.types import ImuSeries, PoseSeries, StateSeries

SIMULATION_YAML = "simulation.yaml"
VIO_TUM_FILE = "vio_tum.txt"
SIMULATION_YAML_VERSION = 1

IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
IMU_TEMPERATURE_COLUMN = "temperature [degC]"
MOCAP_HEADER = (
    "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"
)
POSITION_HEADER = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m]"
GT_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
    "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
    "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)


def _csv_text(header: str, t_ns: np.ndarray, values: np.ndarray) -> str:
    """EuRoC CSV: ``header`` then ``int_ns,v1,...`` lines with shortest round-trip floats."""
    stamps = np.asarray(t_ns, dtype=np.int64).tolist()
    rows = np.asarray(values, dtype=np.float64).tolist()
    lines = [header]
    lines.extend(f"{t}," + ",".join(map(repr, row)) for t, row in zip(stamps, rows))
    lines.append("")
    return "\n".join(lines)


def _imu_csv_text(imu: ImuSeries) -> str:
    """``imu0/data.csv``: the EuRoC columns, and the temperature as a last column when there is one."""
    if imu.temperature_degc is None:
        return _csv_text(IMU_HEADER, imu.t_ns, imu.imu_6)
    values = np.column_stack([imu.imu_6, imu.temperature_degc])
    return _csv_text(f"{IMU_HEADER},{IMU_TEMPERATURE_COLUMN}", imu.t_ns, values)


def _matrix_yaml(T: np.ndarray) -> str:
    rows = [", ".join(repr(float(x)) for x in r) for r in np.asarray(T, dtype=float)]
    body = ",\n         ".join(rows)
    return f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{body}]\n"


def imu_sensor_yaml(sim: Simulation) -> str:
    """``mav0/imu0/sensor.yaml`` in EuRoC/Kalibr style with the REPORTED noise values."""
    cal = sim.sequence.calibration
    return (
        "# General sensor definitions.\n"
        "sensor_type: imu\n"
        "comment: biasgt simulated IMU (noise values below are the reported datasheet values)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        + _matrix_yaml(cal.T_body_imu)
        + f"rate_hz: {cal.rate_hz!r}\n\n"
        "# inertial sensor noise model parameters (static)\n"
        f"gyroscope_noise_density: {cal.gyro_noise_density!r}     # [ rad / s / sqrt(Hz) ]\n"
        f"gyroscope_random_walk: {cal.gyro_random_walk!r}       # [ rad / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_noise_density: {cal.acc_noise_density!r}  # [ m / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_random_walk: {cal.acc_random_walk!r}    # [ m / s^3 / sqrt(Hz) ]\n"
    )


def _pose_sensor_yaml(sensor_type: str, comment: str, T: np.ndarray | None) -> str:
    text = f"# General sensor definitions.\nsensor_type: {sensor_type}\ncomment: {comment}\n"
    if T is not None:
        text += "\n# Sensor extrinsics wrt. the body-frame (the IMU): T_imu_<tracked frame>.\n" + _matrix_yaml(T)
    return text


def _truth_dict(sim: Simulation) -> dict[str, Any]:
    tr = sim.truth
    pt = tr.poses
    b = tr.bias
    return {
        "pose_stream": pt.stream,
        "tracked_frame": pt.frame,
        "pose_time_offset_s": pt.clock_offset_s,
        "pose_time_offset_ns": int(pt.clock_offset_ns),
        f"T_imu_{pt.frame}": np.asarray(pt.T_imu_frame, dtype=float).tolist(),
        "extrinsic_known": bool(sim.config.poses.extrinsic_known),
        "gravity_mps2": np.asarray(tr.gravity_mps2, dtype=float).tolist(),
        "imu_start_ns": int(tr.t_ns[0]),
        "imu_samples": int(len(tr.t_ns)),
        "motion_source": tr.motion_source.value,
        "bias_source": tr.bias_source.value,
        "turn_on_bias_gyro_radps": b.turn_on_gyro_radps.tolist(),
        "turn_on_bias_acc_mps2": b.turn_on_acc_mps2.tolist(),
        "temperature_coeff_gyro_radps_per_degc": b.temp_coeff_gyro.tolist(),
        "temperature_coeff_acc_mps2_per_degc": b.temp_coeff_acc.tolist(),
        "gyro_matrix": tr.matrices.gyro_matrix.tolist(),
        "acc_matrix": tr.matrices.acc_matrix.tolist(),
        "gyro_g_sensitivity": tr.matrices.gyro_g_sensitivity.tolist(),
        "dropout_intervals_ns": pt.dropout_intervals_ns.astype(np.int64).tolist(),
        "outlier_stamps_ns": pt.outlier_stamps_ns.astype(np.int64).tolist(),
        "true_noise": {
            "gyroscope_noise_density": sim.config.imu.gyro_noise_density if sim.config.imu.white_noise else 0.0,
            "accelerometer_noise_density": sim.config.imu.acc_noise_density if sim.config.imu.white_noise else 0.0,
            "gyroscope_random_walk": sim.config.imu.gyro_random_walk if sim.config.imu.bias_random_walk else 0.0,
            "accelerometer_random_walk": sim.config.imu.acc_random_walk if sim.config.imu.bias_random_walk else 0.0,
        },
        "reported_noise": {
            "gyroscope_noise_density": sim.sequence.calibration.gyro_noise_density,
            "accelerometer_noise_density": sim.sequence.calibration.acc_noise_density,
            "gyroscope_random_walk": sim.sequence.calibration.gyro_random_walk,
            "accelerometer_random_walk": sim.sequence.calibration.acc_random_walk,
        },
        "files": {
            "imu": "mav0/imu0/data.csv",
            "ground_truth": "mav0/state_groundtruth_estimate0/data.csv",
        },
    }


def simulation_yaml(sim: Simulation) -> str:
    """Text of ``simulation.yaml``: format version, name, seed, resolved config and truth."""
    doc = {
        "biasgt_simulation": SIMULATION_YAML_VERSION,
        "name": sim.sequence.name,
        "seed": int(sim.config.seed),
        "config": sim.config.to_dict(),
        "truth": _truth_dict(sim),
    }
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def read_simulation_yaml(path: str | Path) -> dict[str, Any]:
    """Load ``simulation.yaml`` (a folder or the file) as a dict (``truth``, ``config``, ``seed``)."""
    path = Path(path)
    if path.is_dir():
        path = path / SIMULATION_YAML
    if not path.is_file():
        raise ConfigError("not a biasgt simulation (no simulation.yaml)", path=path)
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    if not isinstance(data, dict) or data.get("biasgt_simulation") != SIMULATION_YAML_VERSION:
        raise ConfigError("unknown simulation.yaml version", path=path, field="biasgt_simulation")
    return data


def write_simulation(
    sim: Simulation,
    out_dir: str | Path,
    *,
    pose_format: PoseFormat | None = None,
    bag: Any | None = None,
) -> Path:
    """Write the simulation as an ASL folder (atomically).

    Args:
        sim: Result of :func:`pipeline.sim.simulate`.
        out_dir: Output folder; replaced only once the new content is complete.
        pose_format: How to write the pose stream; default the config's format. POSITION writes
            only the positions of a 6-DoF stream; MOCAP and VIO need a stream with orientation.
        bag: A :class:`pipeline.io.rosbag.formats.RosVersion` (or "ros1"/"ros2") to also write
            ``sim.bag`` (ROS1) or ``sim_ros2/`` (ROS2) with the IMU and the pose stream.

    Returns:
        ``out_dir`` as a Path.

    Raises:
        ConfigError: A pose format the stream cannot provide.
    """
    out_dir = Path(out_dir)
    pose_format = sim.config.poses.format if pose_format is None else PoseFormat(pose_format)
    seq = sim.sequence
    stream_name = sim.truth.poses.stream
    poses = seq.poses[stream_name]
    if pose_format is not PoseFormat.POSITION and poses.quat_wxyz is None:
        raise ConfigError(
            f"the simulated stream is position-only; it cannot be written as {pose_format.value}",
            field="pose_format",
            hint="simulate with poses.format: mocap or vio, or write it as position",
        )
    gt = seq.ground_truth
    assert seq.imu is not None and gt is not None
    known = sim.config.poses.extrinsic_known
    T_frame = sim.truth.poses.T_imu_frame

    with atomic_dir(out_dir) as tmp:
        mav0 = tmp / "mav0"
        (mav0 / "imu0").mkdir(parents=True)
        (mav0 / "imu0" / "data.csv").write_text(_imu_csv_text(seq.imu), encoding="utf-8")
        (mav0 / "imu0" / "sensor.yaml").write_text(imu_sensor_yaml(sim), encoding="utf-8")

        _write_ground_truth(mav0, gt)
        _write_poses(tmp, poses, pose_format, T_frame, known)

        if bag is not None:
            _write_bag(sim, tmp, bag, pose_format)

        out_cfg = sim
        if pose_format is not sim.config.poses.format:
            poses_cfg = dataclasses.replace(sim.config.poses, format=pose_format)
            out_cfg = dataclasses.replace(sim, config=dataclasses.replace(sim.config, poses=poses_cfg))
        (tmp / SIMULATION_YAML).write_text(simulation_yaml(out_cfg), encoding="utf-8")
    return out_dir


def _write_ground_truth(mav0: Path, gt: StateSeries) -> None:
    """``mav0/state_groundtruth_estimate0/``: the true IMU state and bias."""
    gt_dir = mav0 / "state_groundtruth_estimate0"
    gt_dir.mkdir()
    gt_values = np.hstack([gt.p_m, gt.quat_wxyz, gt.v_mps, gt.bias_gyro_radps, gt.bias_acc_mps2])
    (gt_dir / "data.csv").write_text(_csv_text(GT_HEADER, gt.t_ns, gt_values), encoding="utf-8")
    (gt_dir / "sensor.yaml").write_text(
        _pose_sensor_yaml("visual-inertial", "biasgt simulation: the TRUE IMU state and bias", np.eye(4)),
        encoding="utf-8",
    )


def _write_poses(tmp: Path, poses: PoseSeries, pose_format: PoseFormat, T_frame: np.ndarray, known: bool) -> None:
    """The pose stream as ``mav0/mocap0/`` (MOCAP), ``mav0/leica0/`` (POSITION) or a TUM file (VIO);
    its sensor.yaml states the extrinsic ``T_frame`` only when it is ``known``."""
    mav0 = tmp / "mav0"
    if pose_format is PoseFormat.MOCAP:
        d = mav0 / "mocap0"
        d.mkdir()
        (d / "data.csv").write_text(
            _csv_text(MOCAP_HEADER, poses.t_ns, np.hstack([poses.p_m, poses.quat_wxyz])), encoding="utf-8"
        )
        (d / "sensor.yaml").write_text(
            _pose_sensor_yaml("pose", "biasgt simulated motion capture (marker pose)", T_frame if known else None),
            encoding="utf-8",
        )
    elif pose_format is PoseFormat.POSITION:
        d = mav0 / "leica0"
        d.mkdir()
        (d / "data.csv").write_text(_csv_text(POSITION_HEADER, poses.t_ns, poses.p_m), encoding="utf-8")
        lever = np.eye(4)
        lever[:3, 3] = T_frame[:3, 3]
        (d / "sensor.yaml").write_text(
            _pose_sensor_yaml("position", "biasgt simulated position tracker (prism)", lever if known else None),
            encoding="utf-8",
        )
    else:
        write_tum(tmp / VIO_TUM_FILE, poses)


def _write_bag(sim: Simulation, tmp: Path, bag: Any, pose_format: PoseFormat) -> None:
    from pipeline.io.rosbag.formats import PoseMsgType, RosVersion  # rosbags (~0.3 s): only to write a bag
    from pipeline.io.rosbag.writer import write_bag

    version = RosVersion(bag)
    seq = sim.sequence
    stream = sim.truth.poses.stream
    topic = {PoseFormat.MOCAP: "/mocap0/pose", PoseFormat.POSITION: "/leica0/position", PoseFormat.VIO: "/vio/odom"}
    msg = PoseMsgType.ODOMETRY if pose_format is PoseFormat.VIO else PoseMsgType.POSE_STAMPED
    if pose_format is PoseFormat.POSITION and seq.poses[stream].quat_wxyz is not None:
        seq = dataclasses.replace(seq, poses={stream: dataclasses.replace(seq.poses[stream], quat_wxyz=None)})
    target = tmp / ("sim.bag" if version is RosVersion.ROS1 else "sim_ros2")
    write_bag(seq, target, ros_version=version, imu_topic="/imu0", pose_topic=topic[pose_format],
              pose_stream=stream, pose_msg=msg)


__all__ = ["SIMULATION_YAML", "VIO_TUM_FILE", "read_simulation_yaml", "simulation_yaml", "write_simulation"]
