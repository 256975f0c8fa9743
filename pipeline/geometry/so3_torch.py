"""SO(3) helpers in PyTorch (conventions: :mod:`pipeline.geometry`).

The torch functions follow the dtype and device of their inputs, never leave the device,
and are differentiable everywhere they are smooth, in particular at zero angle: ``so3_exp``
uses cancellation-free closed forms with the single ``0/0`` point clamped away, ``so3_log`` a
Taylor series below 1e-3 rad, and ``torch.where`` guards keep unused branches free of ``nan``
gradients. They are meant for float32 and float64.
"""

from __future__ import annotations

import torch

__all__ = [
    "hat",
    "vee",
    "so3_exp",
    "so3_exp_entries",
    "so3_log",
    "quat_wxyz_to_matrix",
    "matrix_to_quat_wxyz",
]

# so3_exp clamps the squared angle to this (see _sinc_coefficients); 1/it is finite in float32.
_EXP_MIN_THETA2 = 1e-30
# Below this squared vector-part norm (|q_xyz| < 1e-3) ``so3_log`` uses the series of atan(x)/x.
_LOG_TAYLOR_N2 = 1e-6



def hat(phi: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of a vector: ``hat(a) @ b == cross(a, b)``.

    Args:
        phi: Vectors, [..., 3].

    Returns:
        Skew-symmetric matrices, [..., 3, 3].
    """
    x, y, z = phi.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack(
        (
            torch.stack((zero, -z, y), -1),
            torch.stack((z, zero, -x), -1),
            torch.stack((-y, x, zero), -1),
        ),
        -2,
    )


def vee(M: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`hat` (uses the antisymmetric part, so it also accepts non-skew input).

    Args:
        M: Matrices, [..., 3, 3].

    Returns:
        Vectors, [..., 3].
    """
    return 0.5 * torch.stack(
        (M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]), -1
    )


def _sinc_coefficients(theta2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``A = sin(t)/t`` and ``B = (1 - cos t)/t^2`` from ``t^2``, exact at and near zero.

    Neither quotient needs a Taylor branch: ``sin(t)/t`` has no cancellation, and
    ``B = 0.5 (sin(t/2)/(t/2))^2`` is the cancellation-free form of ``(1 - cos t)/t^2``, so both
    are correct to the last bit for every ``t > 0`` (``sin(x) == x`` in floating point for
    ``x < 1e-8``, so ``A == 1`` and ``B == 0.5`` exactly there, which *is* the Taylor value).
    The only singular point, ``t = 0``, is removed by clamping ``t^2`` to 1e-30 (representable in
    float32): the clamp passes no gradient to ``t^2`` below it, which is exact at ``t = 0``
    because A and B are even in ``t`` (``dA/dphi = dB/dphi = 0`` there). Above the clamp the
    autograd derivative of A carries an absolute error ~eps/t, but it enters ``d Exp/d phi``
    multiplied by ``[phi]x`` (size t), so the Jacobian is accurate to ~eps for every angle
    (tested with ``gradcheck`` at 0, 1e-7 and 1e-3 rad). This avoids two ``torch.where`` and
    two polynomials per call, which matters in the integrator's hot loop.
    """
    theta = torch.sqrt(theta2.clamp_min(_EXP_MIN_THETA2))
    half = 0.5 * theta
    u = torch.sin(half) / half
    return torch.sin(theta) / theta, 0.5 * u * u


def so3_exp_entries(
    x: torch.Tensor, y: torch.Tensor, z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor,
           torch.Tensor, torch.Tensor]:
    """The nine entries of ``Exp(phi)``, row-major, from the components of ``phi``.

    The building block of :func:`so3_exp`, exposed for code that keeps a
    structure-of-arrays layout (the integrator works on [T, 3, B] and wants [T, 3, 3, B]).

    Args:
        x, y, z: Components of the rotation vectors, any (equal) shape [...].

    Returns:
        ``(r00, r01, r02, r10, r11, r12, r20, r21, r22)``, each [...].
    """
    theta2 = x * x + y * y + z * z
    a, b = _sinc_coefficients(theta2)
    c = 1.0 - b * theta2  # cos(theta)
    ax, ay, az = a * x, a * y, a * z
    bx, by = b * x, b * y
    bxy, bxz, byz = bx * y, bx * z, by * z
    return (c + bx * x, bxy - az, bxz + ay, bxy + az, c + by * y, byz - ax, bxz - ay, byz + ax, c + b * z * z)


def so3_exp(phi: torch.Tensor) -> torch.Tensor:
    """Exponential map (Rodrigues): rotation vector -> rotation matrix.

    ``Exp(phi) = cos(t) I + A [phi]x + B phi phi^T`` with ``A = sin(t)/t``,
    ``B = (1 - cos t)/t^2``, ``t = |phi|`` (and ``cos t = 1 - B t^2``). A and B are evaluated in
    cancellation-free forms, so the map is exact near and at ``phi = 0`` and its gradient is
    finite and correct there (``d Exp / d phi_i = hat(e_i)`` at zero); see
    ``_sinc_coefficients`` for why no Taylor branch is needed.

    Args:
        phi: Rotation vectors, [..., 3] (rad).

    Returns:
        Rotation matrices, [..., 3, 3], same dtype and device as ``phi``.
    """
    return torch.stack(so3_exp_entries(*phi.unbind(-1)), -1).unflatten(-1, (3, 3))


def _sqrt_positive(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(max(x, 0))`` with a zero (not infinite) gradient where ``x <= 0``."""
    pos = x > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x))


def matrix_to_quat_wxyz(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrix -> unit Hamilton quaternion, scalar first, with ``w >= 0``.

    Shepperd's method: of the four algebraically equivalent formulas the one with the
    largest (well-conditioned) denominator is used, so the result is accurate for every
    angle, including 0 and pi.

    Args:
        R: Rotation matrices, [..., 3, 3].

    Returns:
        Quaternions ``quat_wxyz``, [..., 4], normalised, ``w >= 0``.
    """
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # q_abs[i] = 2 |q_i| (i = w, x, y, z).
    q_abs = _sqrt_positive(
        torch.stack(
            (
                1.0 + m00 + m11 + m22,
                1.0 + m00 - m11 - m22,
                1.0 - m00 + m11 - m22,
                1.0 - m00 - m11 + m22,
            ),
            -1,
        )
    )
    # Row i is 4 q_i * q (i.e. proportional to q), computed without square roots except q_i.
    candidates = torch.stack(
        (
            torch.stack((q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01), -1),
            torch.stack((m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20), -1),
            torch.stack((m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21), -1),
            torch.stack((m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2), -1),
        ),
        -2,
    )
    # max(q_abs) >= 1 for a rotation; the floor only guards the unselected rows.
    candidates = candidates / (2.0 * q_abs.clamp_min(0.1)[..., None])
    idx = q_abs.argmax(-1)
    q = torch.gather(candidates, -2, idx[..., None, None].expand(*idx.shape, 1, 4)).squeeze(-2)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quat_wxyz_to_matrix(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """Hamilton quaternion (scalar first) -> rotation matrix. The input is normalised first.

    Args:
        quat_wxyz: Quaternions, [..., 4] (any non-zero norm).

    Returns:
        Rotation matrices, [..., 3, 3].
    """
    q = quat_wxyz / torch.linalg.vector_norm(quat_wxyz, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        (
            torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
            torch.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
            torch.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
        ),
        -2,
    )


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Logarithm map: rotation matrix -> rotation vector with ``|phi| <= pi``.

    Goes through :func:`matrix_to_quat_wxyz` (accurate at every angle) and
    ``phi = 2 atan2(|q_xyz|, w) q_xyz / |q_xyz|``, ``w >= 0``; the factor
    ``atan2(n, w)/n`` uses its series ``(1 - x^2/3 + x^4/5)/w``, ``x = n/w``, for
    ``n < 1e-3``, so values and gradients are finite at the identity. At exactly pi the sign
    of ``phi`` is arbitrary (both are correct).

    Args:
        R: Rotation matrices, [..., 3, 3].

    Returns:
        Rotation vectors, [..., 3] (rad).
    """
    q = matrix_to_quat_wxyz(R)
    w = q[..., 0]
    xyz = q[..., 1:]
    n2 = (xyz * xyz).sum(-1)
    small = n2 < _LOG_TAYLOR_N2
    n = torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    scale_closed = 2.0 * torch.atan2(n, w) / n
    # In the small branch w ~ 1, so 1/w is safe; guard it anyway for the unused lanes.
    w_safe = torch.where(small, w, torch.ones_like(w))
    x2 = n2 / (w_safe * w_safe)
    scale_taylor = 2.0 / w_safe * (1.0 - x2 / 3.0 + x2 * x2 / 5.0)
    return torch.where(small, scale_taylor, scale_closed)[..., None] * xyz
