"""The project's one IMU integration engine (PyTorch; batched, differentiable, CPU or CUDA).

Used for the 1-second integration check of recovered biases, for evaluation (PRMSE / ROE)
and as the differentiable indirect-supervision loss in training. Do not write a second one.

Model (strapdown kinematics, ``R`` = world-from-imu, gravity ``g`` in world, e.g. (0, 0, -9.81))::

    dR/dt = R [w - b_g]x,    dv/dt = g + R (a - b_a),    dp/dt = v

``w`` (rad/s) and ``a`` (m/s^2) are instantaneous samples at the stamps ``t_0 .. t_{T-1}``,
``h_k = t_{k+1} - t_k`` and ``f_k = g + R_k (a_k - b_a,k)``. Two schemes (:class:`IntegrationScheme`):

EULER (AirIMU / GTSAM preintegration style, sample k held over [t_k, t_{k+1}]; first order)::

    R_{k+1} = R_k Exp(w_k h_k);  v_{k+1} = v_k + f_k h_k;  p_{k+1} = p_k + v_k h_k + 1/2 f_k h_k^2

MIDPOINT (default; signals linear between samples; second order)::

    R_{k+1} = R_k Exp(1/2 (w_k + w_{k+1}) h_k)              # mid-point rate
    v_{k+1} = v_k + 1/2 (f_k + f_{k+1}) h_k                  # trapezoid
    p_{k+1} = p_k + v_k h_k + 1/6 (2 f_k + f_{k+1}) h_k^2    # exact double integral of the linear f

Inside, vectors are laid out time-major with the batch last ([T, 3, B], [T, 3, 3, B]) and time
is processed in cache-sized blocks; v and p at the window end are weighted reductions of ``f``.
Everything stays on the inputs' device and dtype and is differentiable with autograd (w.r.t.
gyro, acc, biases, dt and the initial state). Design notes: ``docs/internals.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pipeline.errors import DataError
from pipeline.geometry.so3_torch import so3_exp_entries
from pipeline.types import IntegrationScheme

__all__ = ["IntegrationScheme", "IntegrationResult", "integrate", "integrate_numpy"]


@dataclass(frozen=True)
class IntegrationResult:
    """State at the last stamp and, optionally, at every stamp.

    Holds ``torch.Tensor`` from :func:`integrate` and ``np.ndarray`` from
    :func:`integrate_numpy`.

    Attributes:
        R: World-from-imu orientation at ``t_{T-1}``, [B, 3, 3].
        v: Velocity in world at ``t_{T-1}``, [B, 3] (m/s).
        p: Position in world at ``t_{T-1}``, [B, 3] (m).
        R_traj: Orientation at every stamp, [B, T, 3, 3] (``R_traj[:, 0] == R0``), or None
            unless ``return_trajectory``.
        v_traj: Velocity at every stamp, [B, T, 3], or None.
        p_traj: Position at every stamp, [B, T, 3], or None.
    """

    R: Any
    v: Any
    p: Any
    R_traj: Any = None
    v_traj: Any = None
    p_traj: Any = None


def _check_shape(name: str, x: torch.Tensor, shape: tuple[int, ...], hint: str) -> torch.Tensor:
    try:
        return x.expand(shape)
    except RuntimeError:
        raise DataError(f"{name} has shape {tuple(x.shape)}, expected {list(shape)}", field=name, hint=hint) from None


def _as_tensor(x: Any, like: torch.Tensor) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(dtype=like.dtype, device=like.device)
    return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=like.dtype, device=like.device)


def _bias(name: str, bias: Any, like: torch.Tensor) -> torch.Tensor | None:
    """A bias in the internal layout: [1, 3, B] for [B, 3] input, [T, 3, B] for [B, T, 3]."""
    if bias is None:
        return None
    b = _as_tensor(bias, like)
    B, T, _ = like.shape
    if b.dim() == 2:  # [B, 3]: constant over the window
        return _check_shape(name, b, (B, 3), "pass [B, 3] or [B, T, 3]").t().unsqueeze(0)
    return _to_internal(_check_shape(name, b, (B, T, 3), "pass [B, 3] or [B, T, 3]"))


def _time_block(B: int, n_steps: int, device: torch.device) -> int:
    """Steps per block: ~64k step-windows on CPU (cache-sized), everything at once on GPU."""
    if device.type != "cpu":
        return max(n_steps, 1)
    return max(4, min(n_steps, _CPU_BLOCK_ELEMENTS // max(B, 1)))


_CPU_BLOCK_ELEMENTS = 1 << 16


def _end_weights(h: torch.Tensor, scheme: IntegrationScheme) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weights that give the end state as a linear function of the samples ``f_k``.

    With ``tail_j = sum_{k>j} h_k`` (over steps) and the increments ``dv_j``, ``dp_j`` of the
    module docstring, ``v_end = v0 + sum_j dv_j`` and ``p_end = p0 + H v0 + sum_j (tail_j dv_j +
    dp_acc_j)``; collecting the coefficient of each ``f_k`` gives ``alpha_k`` and ``beta_k``.

    Args:
        h: Step lengths, [T-1, 1, Bh] (Bh = 1 or B).
        scheme: The integration scheme.

    Returns:
        ``(alpha, beta, H)``: [T, 1, Bh], [T, 1, Bh], [1, Bh].
    """
    H = h.sum(0)
    tail = H - torch.cumsum(h, 0)  # sum of the step lengths after step j
    zero = torch.zeros_like(h[:1])
    h2 = h * h
    if scheme is IntegrationScheme.MIDPOINT:
        hv = 0.5 * h  # dv_j = h_j/2 (f_j + f_{j+1})
        th = tail * hv
        alpha = torch.cat((hv, zero), 0) + torch.cat((zero, hv), 0)
        # dp_acc_j = h_j^2/6 (2 f_j + f_{j+1})
        beta = torch.cat((th + h2 / 3.0, zero), 0) + torch.cat((zero, th + h2 / 6.0), 0)
    else:
        alpha = torch.cat((h, zero), 0)  # dv_j = h_j f_j
        beta = torch.cat((tail * h + 0.5 * h2, zero), 0)  # dp_acc_j = h_j^2/2 f_j
    return alpha, beta, H


def _to_internal(x: torch.Tensor) -> torch.Tensor:
    """[B, ...] -> [..., B] contiguous, as one 2-D transpose (torch copies 2-D transposes in
    cache-friendly tiles; a general permute with an inner size of 3 is ~3x slower)."""
    B = x.shape[0]
    return x.reshape(B, -1).t().contiguous().reshape(*x.shape[1:], B)


def _from_internal(x: torch.Tensor) -> torch.Tensor:
    """[..., B] -> [B, ...] contiguous (inverse of :func:`_to_internal`)."""
    B = x.shape[-1]
    return x.reshape(-1, B).t().contiguous().reshape(B, *x.shape[:-1])


def _rotate(R: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``R x`` in the internal layout: R [..., 3, 3, B], x [..., 3, B] -> [..., 3, B]."""
    out = R[..., :, 0, :] * x[..., 0:1, :]
    out.addcmul_(R[..., :, 1, :], x[..., 1:2, :])
    out.addcmul_(R[..., :, 2, :], x[..., 2:3, :])
    return out


def integrate(
    gyro_radps: torch.Tensor,
    acc_mps2: torch.Tensor,
    dt_s: torch.Tensor | float,
    R0: torch.Tensor,
    v0: torch.Tensor,
    p0: torch.Tensor,
    *,
    gravity_mps2: torch.Tensor | Sequence[float],
    bias_gyro_radps: torch.Tensor | None = None,
    bias_acc_mps2: torch.Tensor | None = None,
    scheme: IntegrationScheme = IntegrationScheme.MIDPOINT,
    return_trajectory: bool = False,
) -> IntegrationResult:
    """Integrate batches of IMU windows from an initial state (strapdown, see module docstring).

    dtype and device follow ``gyro_radps``; every other input is converted to them. The result
    is differentiable w.r.t. every tensor input.

    Args:
        gyro_radps: Angular rate samples at stamps ``t_0..t_{T-1}``, [B, T, 3] (rad/s).
        acc_mps2: Specific-force samples at the same stamps, [B, T, 3] (m/s^2).
        dt_s: Intervals ``t_{k+1} - t_k``, [B, T-1] (or anything broadcastable to it, e.g.
            [T-1]) or a float (s).
        R0: World-from-imu orientation at ``t_0``, [B, 3, 3] (broadcastable, e.g. [3, 3]).
        v0: Velocity in world at ``t_0``, [B, 3] (m/s) (broadcastable).
        p0: Position in world at ``t_0``, [B, 3] (m) (broadcastable).
        gravity_mps2: Gravity vector in world, [3], e.g. ``(0, 0, -9.81)``.
        bias_gyro_radps: Gyro bias subtracted from ``gyro_radps``, [B, T, 3] or [B, 3]
            (constant over the window), or None.
        bias_acc_mps2: Accelerometer bias subtracted from ``acc_mps2``, [B, T, 3] or [B, 3], or
            None.
        scheme: :class:`IntegrationScheme` (default MIDPOINT, second order).
        return_trajectory: Also return the state at every stamp.

    Returns:
        :class:`IntegrationResult` with tensors (state at ``t_{T-1}``; trajectories if asked).

    Raises:
        DataError: When shapes do not match.
        ValueError: When ``scheme`` is not an :class:`IntegrationScheme` value.
    """
    scheme = IntegrationScheme(scheme)
    w, a, R0, v0, p0, g, bg, ba, h = _checked_inputs(gyro_radps, acc_mps2, dt_s, R0, v0, p0, gravity_mps2,
                                                     bias_gyro_radps, bias_acc_mps2)
    B, T, _ = w.shape

    # Internal layout (see module docstring): [T, 3, B] vectors, [T, 3, 3, B] matrices.
    wt = _to_internal(w)
    at = _to_internal(a)
    if bg is not None:
        wt = wt - bg
    if ba is not None:
        at = at - ba
    R0t = _to_internal(R0)  # [3, 3, B]
    v0t = v0.transpose(0, 1).contiguous()  # [3, B]
    p0t = p0.transpose(0, 1).contiguous()
    gt = g.reshape(3, 1)
    if T == 1:
        return _result(R0t[None], v0t[None], p0t[None], return_trajectory)
    ht = _step_lengths(h, B, T)
    midpoint = scheme is IntegrationScheme.MIDPOINT
    R, ra, R_blocks = _orientations(R0t, wt, at, ht, midpoint, return_trajectory, _time_block(B, T - 1, w.device))
    if not return_trajectory:
        return _end_state(R, ra, ht, v0t, p0t, gt, scheme)
    return _trajectory(ra, R_blocks, ht, v0t, p0t, gt, midpoint)


def _checked_inputs(
    gyro_radps: torch.Tensor, acc_mps2: torch.Tensor, dt_s: torch.Tensor | float, R0: torch.Tensor,
    v0: torch.Tensor, p0: torch.Tensor, gravity_mps2: torch.Tensor | Sequence[float],
    bias_gyro_radps: torch.Tensor | None, bias_acc_mps2: torch.Tensor | None,
) -> tuple[torch.Tensor, ...]:
    """:func:`integrate`'s inputs as tensors of ``gyro_radps``'s dtype and device, shapes checked:
    ``(w, a, R0, v0, p0, g, bg, ba, h)``.

    Raises:
        DataError: When shapes do not match.
    """
    if not isinstance(gyro_radps, torch.Tensor):
        raise DataError("gyro_radps must be a torch.Tensor (use integrate_numpy for numpy)", field="gyro_radps")
    if gyro_radps.dim() != 3 or gyro_radps.shape[-1] != 3 or gyro_radps.shape[1] < 1:
        raise DataError(
            f"gyro_radps has shape {tuple(gyro_radps.shape)}, expected [B, T, 3] with T >= 1",
            field="gyro_radps",
            hint="add a batch dimension with gyro[None] for a single window",
        )
    w = gyro_radps
    B, T, _ = w.shape
    a = _check_shape("acc_mps2", _as_tensor(acc_mps2, w), (B, T, 3), "acc and gyro must have the same shape")
    R0 = _check_shape("R0", _as_tensor(R0, w), (B, 3, 3), "pass [B, 3, 3] world-from-imu rotations")
    v0 = _check_shape("v0", _as_tensor(v0, w), (B, 3), "pass [B, 3]")
    p0 = _check_shape("p0", _as_tensor(p0, w), (B, 3), "pass [B, 3]")
    g = _check_shape("gravity_mps2", _as_tensor(gravity_mps2, w), (3,), "pass a 3-vector such as (0, 0, -9.81)")
    bg = _bias("bias_gyro_radps", bias_gyro_radps, w)
    ba = _bias("bias_acc_mps2", bias_acc_mps2, w)
    h = _as_tensor(dt_s, w)
    try:
        torch.broadcast_shapes(h.shape, (B, T - 1))
    except RuntimeError:
        raise DataError(
            f"dt_s has shape {tuple(h.shape)}, expected a float or [B, T-1] = {[B, T - 1]}",
            field="dt_s",
            hint="pass the intervals t_{k+1} - t_k in seconds",
        ) from None
    return w, a, R0, v0, p0, g, bg, ba, h


def _step_lengths(h: torch.Tensor, B: int, T: int) -> torch.Tensor:
    """Step lengths as [T-1, 1, Bh], Bh = 1 when all windows share them."""
    if h.dim() == 0:
        ht = h.expand(T - 1).reshape(T - 1, 1, 1)
    elif h.dim() == 1 or h.shape[0] == 1:
        ht = h.reshape(-1).expand(T - 1).reshape(T - 1, 1, 1)
    else:
        ht = h.expand(B, T - 1).transpose(0, 1).unsqueeze(1).contiguous()
    return ht


def _orientations(R0t: torch.Tensor, wt: torch.Tensor, at: torch.Tensor, ht: torch.Tensor, midpoint: bool,
                  return_trajectory: bool, blk: int
                  ) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor] | None]:
    """Block loop over time: Exp of every step, cumulative orientation, R_k a_k.

    Returns:
        ``(R, ra, R_blocks)``: the end orientation [3, 3, B], R_k a_k in blocks of [n, 3, B], and
        (with ``return_trajectory``) the orientations in blocks of [n, 3, 3, B].
    """
    n_steps = wt.shape[0] - 1
    R = R0t
    ra = [_rotate(R0t, at[0])[None]]  # R_k a_k, blocks of [n, 3, B]
    R_blocks = [R0t[None]] if return_trajectory else None
    for s in range(0, n_steps, blk):
        e = min(s + blk, n_steps)  # this block does steps s..e-1 and yields R_{s+1}..R_e
        if midpoint:
            phi = (0.5 * ht[s:e]) * (wt[s:e] + wt[s + 1 : e + 1])  # mid-point rate * h
        else:
            phi = ht[s:e] * wt[s:e]
        dR = torch.stack(so3_exp_entries(phi[:, 0], phi[:, 1], phi[:, 2]), 1).unflatten(1, (3, 3))
        Rs = []
        for k in range(e - s):
            # R <- R @ dR[k] as three broadcast multiply-adds. The in-place addcmul_ only
            # touches the fresh product, which no backward function needs: autograd is exact.
            step = dR[k]
            R_next = R[:, 0:1] * step[0:1]
            R_next.addcmul_(R[:, 1:2], step[1:2])
            R_next.addcmul_(R[:, 2:3], step[2:3])
            Rs.append(R_next)
            R = R_next
        Rb = torch.stack(Rs, 0)  # [n, 3, 3, B]
        ra.append(_rotate(Rb, at[s + 1 : e + 1]))
        if R_blocks is not None:
            R_blocks.append(Rb)
    return R, ra, R_blocks


def _end_state(R: torch.Tensor, ra: list[torch.Tensor], ht: torch.Tensor, v0t: torch.Tensor, p0t: torch.Tensor,
               gt: torch.Tensor, scheme: IntegrationScheme) -> IntegrationResult:
    """The end state as weighted sums of f_k = g + R_k a_k (see _end_weights)."""
    alpha, beta, H = _end_weights(ht, scheme)
    v_end = v0t + gt * alpha.sum(0)
    p_end = p0t + H * v0t + gt * beta.sum(0)
    k = 0
    for block in ra:
        n = block.shape[0]
        v_end = v_end + (alpha[k : k + n] * block).sum(0)
        p_end = p_end + (beta[k : k + n] * block).sum(0)
        k += n
    return _result(R[None], v_end[None], p_end[None], False)


def _trajectory(ra: list[torch.Tensor], R_blocks: list[torch.Tensor], ht: torch.Tensor, v0t: torch.Tensor,
                p0t: torch.Tensor, gt: torch.Tensor, midpoint: bool) -> IntegrationResult:
    """The state at every stamp: increments per step, then cumulative sums over time."""
    f = torch.cat(ra, 0) + gt  # [T, 3, B]
    f0, f1 = f[:-1], f[1:]
    if midpoint:
        dv = (0.5 * ht) * (f0 + f1)  # trapezoid
        dp_acc = (ht * ht / 6.0) * (2.0 * f0 + f1)  # exact double integral of the linear f
    else:
        dv = ht * f0
        dp_acc = (0.5 * ht * ht) * f0
    vt = torch.cat((v0t[None], v0t + torch.cumsum(dv, 0)), 0)  # [T, 3, B]
    dp = ht * vt[:-1] + dp_acc
    pt = torch.cat((p0t[None], p0t + torch.cumsum(dp, 0)), 0)
    return _result(torch.cat(R_blocks, 0), vt, pt, True)


def _result(Rt: torch.Tensor, vt: torch.Tensor, pt: torch.Tensor, trajectory: bool) -> IntegrationResult:
    """Back from the internal layout ([T, 3, 3, B], [T, 3, B]) to [B, ...] tensors."""
    R, v, p = _from_internal(Rt[-1]), _from_internal(vt[-1]), _from_internal(pt[-1])
    if not trajectory:
        return IntegrationResult(R, v, p)
    return IntegrationResult(R, v, p, _from_internal(Rt), _from_internal(vt), _from_internal(pt))


def integrate_numpy(
    gyro_radps: np.ndarray,
    acc_mps2: np.ndarray,
    dt_s: np.ndarray | float,
    R0: np.ndarray,
    v0: np.ndarray,
    p0: np.ndarray,
    *,
    gravity_mps2: np.ndarray | Sequence[float],
    bias_gyro_radps: np.ndarray | None = None,
    bias_acc_mps2: np.ndarray | None = None,
    scheme: IntegrationScheme = IntegrationScheme.MIDPOINT,
    return_trajectory: bool = False,
) -> IntegrationResult:
    """NumPy convenience wrapper of :func:`integrate` (float64, CPU, no autograd).

    Accepts the batched shapes of :func:`integrate` or a single window: gyro/acc [T, 3],
    dt [T-1] or float, R0 [3, 3], v0/p0 [3], biases [3] or [T, 3]; a single window gives
    unbatched outputs (R [3, 3], v [3], p [3], R_traj [T, 3, 3], ...).

    Returns:
        :class:`IntegrationResult` holding ``np.ndarray`` (float64).
    """
    gyro = np.asarray(gyro_radps, dtype=np.float64)
    single = gyro.ndim == 2

    def batch(x: Any) -> Any:
        if x is None:
            return None
        t = torch.as_tensor(np.asarray(x, dtype=np.float64))
        return t.unsqueeze(0) if single and t.dim() > 0 else t

    with torch.no_grad():
        res = integrate(
            batch(gyro),
            batch(acc_mps2),
            batch(dt_s),
            batch(R0),
            batch(v0),
            batch(p0),
            gravity_mps2=torch.as_tensor(np.asarray(gravity_mps2, dtype=np.float64)),
            bias_gyro_radps=batch(bias_gyro_radps),
            bias_acc_mps2=batch(bias_acc_mps2),
            scheme=scheme,
            return_trajectory=return_trajectory,
        )

    def out(x: torch.Tensor | None) -> np.ndarray | None:
        if x is None:
            return None
        arr = x.numpy()
        return arr[0].copy() if single else arr.copy()

    return IntegrationResult(*(out(x) for x in (res.R, res.v, res.p, res.R_traj, res.v_traj, res.p_traj)))
