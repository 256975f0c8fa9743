"""Sampling backends: how a diffusion model's denoiser ``denoise(x_t [N, T, 6], t [N], code [N, C]) ->
eps [N, T, 6]`` runs while :meth:`training.models.bias_model.BiasModel.sample` draws (one backend per
:class:`training.config.SamplingBackend`).

* ``exact``: the network's own ``denoise``, float32 eager PyTorch. The reference: its samples are the
  same for the same seed however the windows are batched (each window draws its noise from its own
  generator, :class:`training.models.scheduler.WindowNoise`).
* ``bf16``: a copy of the network under ``torch.autocast("cpu", torch.bfloat16)`` (matrix products and
  convolutions in bfloat16, on a core's AMX or AVX512-BF16 units), compiled by ``torch.compile``
  (inductor, weights frozen), with Mish written as ``x n / (n + 2)``, ``n = e^x (e^x + 2)``
  (= ``x tanh(softplus(x))``), one exponential that the compiler fuses with its neighbours. The
  first call of each input shape compiles (tens of seconds); later calls of that shape reuse it.

``bf16`` changes the arithmetic; the tests hold its samples equal to ``exact``'s in distribution (mean
and spread per channel within a tolerance), not value by value. Measured and not kept (slower than
``bf16`` on every diffusion network, and than ``exact`` on some): int8 dynamic quantisation of the
Linear and GRU layers, onnxruntime on the exported denoiser. The condition encoder (once per window)
and the sampler's steps stay float32 PyTorch. What each backend gains is measured by
``benchmarks/learning/sampling.py`` (figures in ``docs/results.md``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch
from torch import nn

from pipeline.errors import ConfigError
from training.config import SamplingBackend

__all__ = ["Denoise", "PAD_ROWS", "prepare_denoiser"]

#: The compiled backend pads a call's rows to a multiple of this (each new shape compiles anew).
PAD_ROWS = 16

#: ``(x_t [N, T, 6], t [N] int64, code [N, C]) -> eps [N, T, 6]`` (float32).
Denoise = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def prepare_denoiser(net: nn.Module, backend: SamplingBackend | str) -> Denoise | None:
    """The denoiser of ``net`` (a diffusion network, eval mode) run by ``backend``; None for ``exact``
    (the network's own ``denoise``).

    Args:
        net: The network (``encode`` / ``denoise``, :mod:`training.networks`).
        backend: Which backend.

    Raises:
        ConfigError: Unknown backend.
    """
    try:
        backend = SamplingBackend(backend)
    except ValueError:
        raise ConfigError(f"sampling backend {backend!r}", field="backend",
                          hint=f"use one of {', '.join(b.value for b in SamplingBackend)}") from None
    if backend is SamplingBackend.EXACT:
        return None
    return _compiled_bf16(net)


class _FastMish(nn.Module):
    """Mish, ``x tanh(softplus(x)) = x n / (n + 2)`` with ``n = e^x (e^x + 2)`` (``x`` itself above 20)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        e = torch.exp(torch.clamp(x, max=20.0))
        n = e * (e + 2.0)
        return torch.where(x > 20.0, x, x * n / (n + 2.0))


def _swap_mish(module: nn.Module) -> nn.Module:
    for name, child in module.named_children():
        if isinstance(child, nn.Mish):
            setattr(module, name, _FastMish())
        else:
            _swap_mish(child)
    return module


def _compiled_bf16(net: nn.Module) -> Denoise:
    """A copy of ``net`` (fast Mish) run under bfloat16 autocast, compiled with frozen weights."""
    fast = _swap_mish(copy.deepcopy(net).eval())

    def run(x: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = fast.denoise(x, t, code)
        return out.float()

    compiled = torch.compile(run, dynamic=False, options={"freezing": True})

    def padded(x: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """Rows padded (repeating the last) to a multiple of :data:`PAD_ROWS`: few shapes, few compilations."""
        n = x.shape[0]
        pad = (-n) % PAD_ROWS
        if pad:
            x, t, code = (torch.cat([v, v[-1:].expand(pad, *v.shape[1:])]) for v in (x, t, code))
        return compiled(x, t, code)[:n]

    return padded
