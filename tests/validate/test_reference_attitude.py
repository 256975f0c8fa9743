"""How an independent reference's attitude sits on the IMU (validation.attitude), on constructed
trajectories whose offsets are known by construction: an IMU mounted x-up (as EuRoC's), yawing
about the world's z, so its up axis is exactly its x axis."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from pipeline.types import PoseSeries, PoseSourceKind
from validation.attitude import MIN_STAMPS, reference_attitude_offset
from validation.reference import ReferenceKind, ReferenceStates

G = np.array([0.0, 0.0, -9.81])
X_UP = Rotation.from_matrix([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # body x -> world z


def _reference(n: int = 2000, rate_hz: float = 200.0) -> ReferenceStates:
    t_s = np.arange(n) / rate_hz
    yaw = 2 * np.pi * t_s / t_s[-1]
    R = (Rotation.from_euler("z", yaw[:, None]) * X_UP).as_matrix()
    p = np.c_[2 * np.cos(yaw), 1.5 * np.sin(yaw), 0.3 * np.sin(3 * yaw)]
    return ReferenceStates(t_ns=(t_s * 1e9).astype(np.int64), R=R, v=np.zeros((n, 3)), p=p,
                           valid=np.ones(n, bool), kind=ReferenceKind.STATE)


def _trajectory(ref: ReferenceStates, W: Rotation, dR: Rotation, step: int = 20) -> PoseSeries:
    k = np.arange(0, len(ref.t_ns), step)
    R = W * Rotation.from_matrix(ref.R[k]) * dR
    return PoseSeries(ref.t_ns[k], W.apply(ref.p[k]) + [5.0, -2.0, 1.0], R.as_quat(scalar_first=True), "imu",
                      PoseSourceKind.GROUND_TRUTH)


@pytest.mark.parametrize("world_deg", [0.0, 20.0])
def test_offset_split_into_tilt_and_heading_as_constructed(world_deg):
    """dR = 2 deg about the up axis (heading) then 0.8 deg about a horizontal one (tilt); the
    trajectory's world frame turned by ``world_deg`` about a tilted axis and shifted."""
    ref = _reference()
    dR = Rotation.from_rotvec(np.radians([2.0, 0.0, 0.8]))  # IMU frame: x is up
    W = Rotation.from_rotvec(np.radians(world_deg) * np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93]))
    off = reference_attitude_offset(ref, _trajectory(ref, W, dR), G)
    assert np.allclose(off.rotvec_deg, np.degrees(dR.as_rotvec()), atol=1e-6)
    assert off.heading_deg == pytest.approx(2.0, abs=1e-6) and off.tilt_deg == pytest.approx(0.8, abs=1e-6)
    assert off.acc_bias_equivalent_mps2 == pytest.approx(9.81 * np.sin(np.radians(0.8)), rel=1e-6)
    assert off.world_deg == pytest.approx(world_deg, abs=1e-6) and off.world_rms_m < 1e-9
    assert off.spread_deg < 1e-6 and off.stamps == 100
    assert "tilt 0.80 deg" in off.note() and "0.137 m/s^2" in off.note()


def test_slerp_between_reference_stamps_and_gaps():
    """Trajectory stamps between the reference's, posed with scipy's Slerp of the reference: no offset
    appears from a rotating reference; stamps beside a gap of the reference are not used."""
    ref = _reference()
    k = np.arange(5, len(ref.t_ns) - 1, 20)
    t_mid = (ref.t_ns[k] + ref.t_ns[k + 1]) // 2
    R_mid = Slerp(ref.t_ns / 1e9, Rotation.from_matrix(ref.R))(t_mid / 1e9)  # scipy's slerp
    p_mid = 0.5 * (ref.p[k] + ref.p[k + 1])
    traj = PoseSeries(t_mid, p_mid, R_mid.as_quat(scalar_first=True), "imu", PoseSourceKind.GROUND_TRUTH)
    off = reference_attitude_offset(ref, traj, G)
    assert np.linalg.norm(off.rotvec_deg) < 1e-6 and off.stamps == len(k)
    ref.valid[k[3]:k[12] + 1] = False  # a gap over ten of the trajectory's stamps
    assert reference_attitude_offset(ref, traj, G).stamps == len(k) - 10


def test_nothing_without_orientations_or_overlap():
    ref = _reference()
    traj = _trajectory(ref, Rotation.identity(), Rotation.identity())
    assert reference_attitude_offset(ref, PoseSeries(traj.t_ns, traj.p_m, None, "prism",
                                                     PoseSourceKind.POSITION_TRACKER), G) is None
    short = PoseSeries(traj.t_ns[:MIN_STAMPS - 1], traj.p_m[:MIN_STAMPS - 1], traj.quat_wxyz[:MIN_STAMPS - 1], "imu",
                       PoseSourceKind.GROUND_TRUTH)
    assert reference_attitude_offset(ref, short, G) is None
