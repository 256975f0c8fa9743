"""The fast NumPy rotation conversions (recovery.solver.rotations) equal SciPy's at every angle up to pi:
the trace formula, the small-angle series, the hand-over to SciPy near pi, either quaternion sign."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recovery.solver.rotations import matrix_to_quat_wxyz, matrix_to_rotvec, quat_to_rotvec, relative_rotvecs

ANGLES = [0.0, 1e-9, 1e-4, 0.1, 2.0, np.pi]


def _rotvecs(max_angle: float, n: int = 5000, seed: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    phi = rng.normal(size=(n, 3))
    phi *= (max_angle * rng.uniform(0.0, 1.0, n) / np.linalg.norm(phi, axis=1))[:, None]
    phi[:3] = [[max_angle, 0.0, 0.0], [0.0, -max_angle, 0.0], [0.0, 0.0, 0.0]]
    return phi


@pytest.mark.parametrize("max_angle", ANGLES)
def test_matrix_to_rotvec_and_quaternion_equal_scipy(max_angle):
    R = Rotation.from_rotvec(_rotvecs(max_angle)).as_matrix()
    q_ref = Rotation.from_matrix(R).as_quat(scalar_first=True)
    q_ref *= np.where(q_ref[:, :1] < 0, -1.0, 1.0)
    q = matrix_to_quat_wxyz(R)
    assert np.all(q[:, 0] >= 0)
    at_pi = np.isclose(q_ref[:, 0], 0.0, atol=1e-12)  # w = 0: q and -q are both canonical
    np.testing.assert_allclose(q[~at_pi], q_ref[~at_pi], atol=2e-15)
    np.testing.assert_allclose(np.abs(q[at_pi]), np.abs(q_ref[at_pi]), atol=2e-15)
    rv = matrix_to_rotvec(R)
    np.testing.assert_allclose(Rotation.from_rotvec(rv).as_matrix(), R, atol=5e-15)
    np.testing.assert_allclose(rv[~at_pi], Rotation.from_matrix(R[~at_pi]).as_rotvec(), atol=5e-15)


@pytest.mark.parametrize("max_angle", ANGLES)
def test_quat_to_rotvec_takes_either_sign(max_angle):
    rot = Rotation.from_rotvec(_rotvecs(max_angle))
    q = rot.as_quat(scalar_first=True)
    ref = rot.as_rotvec()
    inside = np.linalg.norm(ref, axis=1) < np.pi - 1e-9  # at pi, phi and -phi are both right
    for sign in (1.0, -1.0):
        np.testing.assert_allclose(quat_to_rotvec(sign * q)[inside], ref[inside], atol=5e-15)


@pytest.mark.parametrize("step", [1e-9, 1e-4, 0.1, None])
def test_relative_rotvecs_equal_scipy(step):
    """Orientations whose consecutive ones are ``step`` rad apart or less (None: independent uniform
    orientations, every relative angle up to pi)."""
    rng = np.random.default_rng(3)
    if step is None:
        rot = Rotation.random(5000, random_state=4)
    else:
        walk = np.cumsum(rng.normal(size=(5000, 3)) * step / np.sqrt(3), axis=0)
        rot = Rotation.random(random_state=4) * Rotation.from_rotvec(walk)
    ref = (rot[:-1].inv() * rot[1:]).as_rotvec()
    inside = np.linalg.norm(ref, axis=1) < np.pi - 1e-9  # at pi, phi and -phi are both right
    np.testing.assert_allclose(relative_rotvecs(rot)[inside], ref[inside], atol=5e-15)
