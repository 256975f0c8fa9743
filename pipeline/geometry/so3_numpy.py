"""SO(3) helpers in NumPy, through SciPy's :class:`~scipy.spatial.transform.Rotation`
(conventions: :mod:`pipeline.geometry`); no torch, for the processes that do not load it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "hat_np",
    "so3_exp_np",
    "so3_log_np",
    "quat_wxyz_to_matrix_np",
    "matrix_to_quat_wxyz_np",
    "rotation_angle_deg",
]


def hat_np(phi: np.ndarray) -> np.ndarray:
    """NumPy :func:`~pipeline.geometry.so3_torch.hat`: [..., 3] -> [..., 3, 3]."""
    phi = np.asarray(phi, dtype=np.float64)
    out = np.zeros(phi.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -phi[..., 2], phi[..., 1]
    out[..., 1, 0], out[..., 1, 2] = phi[..., 2], -phi[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -phi[..., 1], phi[..., 0]
    return out


def _as_rotation(R: np.ndarray) -> tuple[Rotation, tuple[int, ...]]:
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"expected rotation matrices [..., 3, 3], got shape {R.shape}")
    batch = R.shape[:-2]
    return Rotation.from_matrix(R.reshape(-1, 3, 3)), batch


def so3_exp_np(phi: np.ndarray) -> np.ndarray:
    """Exponential map in NumPy (SciPy): [..., 3] -> [..., 3, 3], float64."""
    phi = np.asarray(phi, dtype=np.float64)
    return Rotation.from_rotvec(phi.reshape(-1, 3)).as_matrix().reshape(phi.shape[:-1] + (3, 3))


def so3_log_np(R: np.ndarray) -> np.ndarray:
    """Logarithm map in NumPy (SciPy): [..., 3, 3] -> [..., 3], float64, ``|phi| <= pi``."""
    rot, batch = _as_rotation(R)
    return rot.as_rotvec().reshape(batch + (3,))


def quat_wxyz_to_matrix_np(quat_wxyz: np.ndarray) -> np.ndarray:
    """Hamilton quaternion, scalar FIRST, -> rotation matrix (normalises the input).

    Args:
        quat_wxyz: [..., 4] as ``(w, x, y, z)``.

    Returns:
        [..., 3, 3] float64.
    """
    q = np.asarray(quat_wxyz, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ValueError(f"expected quaternions [..., 4], got shape {q.shape}")
    mats = Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix()
    return mats.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat_wxyz_np(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> Hamilton quaternion, scalar FIRST, canonical ``w >= 0``.

    Args:
        R: [..., 3, 3].

    Returns:
        ``quat_wxyz`` [..., 4] float64.
    """
    rot, batch = _as_rotation(R)
    q = rot.as_quat(canonical=True, scalar_first=True)
    return q.reshape(batch + (4,))


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray | float:
    """Angle of the relative rotation, ``|Log(R_a^T R_b)|`` in degrees.

    Computed through quaternions (SciPy), so it is accurate for tiny angles too (no
    ``arccos`` of a trace).

    Args:
        R_a: [..., 3, 3].
        R_b: [..., 3, 3] (broadcasts against ``R_a``).

    Returns:
        Angles in degrees, shape [...] (a Python float for single matrices).
    """
    R_a = np.asarray(R_a, dtype=np.float64)
    R_b = np.asarray(R_b, dtype=np.float64)
    R_rel = np.swapaxes(R_a, -1, -2) @ R_b
    rot, batch = _as_rotation(R_rel)
    deg = np.degrees(rot.magnitude()).reshape(batch)
    return float(deg) if deg.ndim == 0 else deg
