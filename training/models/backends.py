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
* ``int8``: a copy of the network with its ``Linear`` and ``GRU`` layers dynamically quantised to int8
  (``torch.ao.quantization.quantize_dynamic``: weights int8 per tensor, activations quantised per call).
* ``onnx``: the denoiser exported to ONNX (opset :data:`training.deploy.export.ONNX_OPSET`) and run by
  onnxruntime on the CPU with PyTorch's intra-op thread count.

Every backend but ``exact`` changes the arithmetic; the tests hold their samples equal to ``exact``'s in
distribution (mean and spread per channel within a tolerance), not value by value. The condition
encoder (once per window) and the sampler's steps stay float32 PyTorch. What each backend gains is
measured by ``benchmarks/learning/sampling.py`` (figures in ``docs/results.md``).
"""

from __future__ import annotations

import copy
import io
import warnings
from collections.abc import Callable

import torch
from torch import nn

from pipeline.errors import ConfigError
from training.config import SamplingBackend

__all__ = ["Denoise", "prepare_denoiser"]

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
    if backend is SamplingBackend.BF16:
        return _compiled_bf16(net)
    if backend is SamplingBackend.INT8:
        return _quantised(net).denoise
    return _onnx(net)


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

    return torch.compile(run, dynamic=False, options={"freezing": True})


def _quantised(net: nn.Module) -> nn.Module:
    """A copy of ``net`` with int8 dynamic ``Linear`` / ``GRU`` layers (the original is untouched)."""
    with warnings.catch_warnings():  # torch.ao.quantization announces its move to torchao
        warnings.simplefilter("ignore")
        from torch.ao.quantization import quantize_dynamic

        return quantize_dynamic(copy.deepcopy(net).eval(), {nn.Linear, nn.GRU}, dtype=torch.qint8)


class _DenoiseGraph(nn.Module):
    """``net.denoise`` as a module's forward (what the ONNX exporter traces)."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        return self.net.denoise(x, t, code)


def _onnx(net: nn.Module) -> Denoise:
    """``net.denoise`` exported to ONNX in memory (traced on the first call's first rows; the row count
    stays dynamic) and run by an onnxruntime CPU session."""
    sessions = []

    def run(x: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        if not sessions:
            sessions.append(_onnx_session(net, (x[:2].float().cpu(), t[:2].cpu(), code[:2].float().cpu())))
        feed = {"x": x.detach().float().cpu().numpy(), "t": t.detach().cpu().numpy(),
                "code": code.detach().float().cpu().numpy()}
        return torch.from_numpy(sessions[0].run(None, feed)[0]).to(x.device)

    return run


def _onnx_session(net: nn.Module, example: tuple[torch.Tensor, ...]) -> object:
    import onnxruntime as ort

    from training.deploy.export import ONNX_OPSET

    buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(_DenoiseGraph(net).eval(), example, buffer, input_names=["x", "t", "code"],
                          output_names=["eps"], dynamic_axes={"x": {0: "n"}, "t": {0: "n"}, "code": {0: "n"}},
                          opset_version=ONNX_OPSET, dynamo=False)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = torch.get_num_threads()
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(buffer.getvalue(), opts, providers=["CPUExecutionProvider"])
