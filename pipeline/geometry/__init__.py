"""Geometry core: rotations (:mod:`~pipeline.geometry.so3_torch` in PyTorch,
:mod:`~pipeline.geometry.so3_numpy` in NumPy), IMU integration (:mod:`~pipeline.geometry.integration`)
and pose-frame transforms (:mod:`~pipeline.geometry.pose_transform`).

Rotation conventions:
    * rotation vectors ``phi`` [..., 3] (axis * angle, rad);
    * ``R`` [..., 3, 3] rotation matrices; ``R_a_b`` maps vectors from frame b to frame a;
    * quaternions are Hamilton, scalar first, ``quat_wxyz`` [..., 4]. SciPy's
      :class:`~scipy.spatial.transform.Rotation` is scalar LAST by default: the NumPy
      helpers always pass ``scalar_first=True`` so callers never see ``xyzw``.
    * ``Exp(phi) = I + sin(theta)/theta [phi]x + (1 - cos(theta))/theta^2 [phi]x^2`` with
      ``theta = |phi|``; ``Log`` is its inverse with ``|Log(R)| <= pi``.
"""
