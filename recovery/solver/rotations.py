"""Fast NumPy rotation conversions for the recovery's hot paths.

SciPy's :class:`~scipy.spatial.transform.Rotation` orthonormalises every matrix it is given and
pays a per-call overhead that dominates batched products of a few thousand rotations; these do
the same conversions with closed forms on rows of arrays. Quaternions are Hamilton, scalar first
(``quat_wxyz``), returned with ``w >= 0``; rotation vectors have ``|phi| <= pi``. Each equals
SciPy's to ~1e-15 (``tests/recover/test_rotations.py``). They live here rather than in
:mod:`pipeline.geometry.so3_numpy`, whose helpers go through SciPy's ``Rotation`` (per-call
overhead, orthonormalisation) for the rest of the project.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["matrix_to_quat_wxyz", "quat_to_rotvec", "matrix_to_rotvec", "relative_rotvecs"]


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Quaternions [M, 4] (``w >= 0``) of rotation matrices ``R`` [M, 3, 3].

    The trace formula where ``w >= 0.3`` (rotations below ~145 deg, every sample a fusion sees in
    practice), SciPy's ``Rotation.from_matrix`` for the rest: equal to SciPy to ~1e-15 for
    orthonormal ``R``, a few times faster (SciPy orthonormalises every matrix first).
    """
    R = np.asarray(R, dtype=float)
    w = 0.5 * np.sqrt(np.maximum(1.0 + R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], 0.0))
    q = np.empty((len(R), 4))
    q[:, 0] = w
    with np.errstate(divide="ignore", invalid="ignore"):  # w = 0 only where SciPy takes over below
        s = 0.25 / w
        q[:, 1] = (R[:, 2, 1] - R[:, 1, 2]) * s
        q[:, 2] = (R[:, 0, 2] - R[:, 2, 0]) * s
        q[:, 3] = (R[:, 1, 0] - R[:, 0, 1]) * s
    far = w < 0.3
    if far.any():
        qf = Rotation.from_matrix(R[far]).as_quat(scalar_first=True)
        q[far] = qf * np.where(qf[:, :1] < 0, -1.0, 1.0)
    return q


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors [M, 3] (``|phi| <= pi``) of unit quaternions ``q`` [M, 4] (wxyz, either
    sign): ``phi = 2 atan2(|q_xyz|, w) q_xyz / |q_xyz|`` with ``w >= 0`` (its series below
    ``|q_xyz| = 1e-3``)."""
    q = np.where(q[:, :1] < 0, -q, q)
    w, xyz = q[:, 0], q[:, 1:]
    n = np.linalg.norm(xyz, axis=1)
    small = n < 1e-3
    x2 = np.where(small, n / np.where(small, w, 1.0), 0.0) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 2.0 / np.where(small, w, 1.0) * (1.0 - x2 / 3.0 + x2 * x2 / 5.0),
                         2.0 * np.arctan2(n, w) / n)
    return scale[:, None] * xyz


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vectors [M, 3] of rotation matrices ``R`` [M, 3, 3] (:func:`matrix_to_quat_wxyz`)."""
    return quat_to_rotvec(matrix_to_quat_wxyz(R))


def relative_rotvecs(rot: Rotation) -> np.ndarray:
    """``(rot[:-1].inv() * rot[1:]).as_rotvec()``, [N - 1, 3], by quaternion products on rows."""
    q = rot.as_quat(scalar_first=True)
    a, b = q[:-1], q[1:]
    rel = np.empty_like(a)  # conj(a) * b
    rel[:, 0] = a[:, 0] * b[:, 0] + np.sum(a[:, 1:] * b[:, 1:], axis=1)
    rel[:, 1:] = a[:, :1] * b[:, 1:] - b[:, :1] * a[:, 1:] - np.cross(a[:, 1:], b[:, 1:])
    return quat_to_rotvec(rel)
