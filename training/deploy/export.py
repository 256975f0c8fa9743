"""Export a trained model with its sampler as one graph: TorchScript or ONNX (``biasgt export``).

The exported graph maps the raw condition window (IMU [B, T, 6], or [B, T, 7] with temperature
last, as the model was trained) to bias in raw units (rad/s, m/s^2):

* a diffusion model: inputs ``imu`` [B, T, C] and ``noise`` [B*K, T, 6] (the initial x_T, the
  K samples of window b in rows b*K .. b*K+K-1, as :meth:`training.models.BiasModel.sample`
  draws them); output ``bias`` [B, K, T, 6]. The sampler (correct DDIM with eta 0, or the
  released code's) and its number of steps are fixed at export time and unrolled, so with the
  same noise the graph reproduces PyTorch's samples;
* a regression / indirect model: input ``imu``; output ``bias`` [B, 1, T, 6].

B and K are dynamic; T is the model's window length. ONNX uses opset :data:`ONNX_OPSET`
through ``torch.onnx.export`` and is run with onnxruntime (:func:`onnx_session`).
"""

from __future__ import annotations

import io
import logging
import warnings
from pathlib import Path

import torch
from torch import nn

from pipeline.files.atomic import atomic_path
from pipeline.errors import BiasgtError, ConfigError
from training.config import IMU_CHANNELS, STEPS, ExportFormat, Sampler

log = logging.getLogger(__name__)

__all__ = ["ExportFormat", "ExportedSampler", "example_inputs", "export_run", "onnx_session", "write_export"]

ONNX_OPSET = 17


class ExportError(BiasgtError):
    """The model cannot be exported (one line naming the file and the fix)."""


class ExportedSampler(nn.Module):
    """A :class:`training.models.BiasModel` and a fixed sampler as one traceable module.

    Args:
        model: The trained model (eval mode).
        sampler: DDIM (eta 0) or RELEASED (diffusion models).
        steps: Sampling steps.
    """

    def __init__(self, model: nn.Module, sampler: Sampler = Sampler.DDIM, steps: int = STEPS) -> None:
        super().__init__()
        self.model = model
        self.sampler = Sampler(sampler)
        if self.sampler is Sampler.DDPM:
            raise ConfigError("the DDPM sampler draws fresh noise every step and is not exported",
                              field="sampler", hint="export with --sampler ddim or released")
        self.diffusion = bool(model.spec.is_diffusion)
        self.timesteps = [int(t) for t in model.scheduler.set_timesteps(steps, self.sampler).tolist()]

    def forward(self, imu: torch.Tensor, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Bias [B, K, T, 6] from the condition ``imu`` [B, T, C] and, for diffusion, ``noise`` [B*K, T, 6]."""
        m = self.model
        cond = m.normalizer.condition(imu)
        B, T = cond.shape[0], cond.shape[1]
        if not self.diffusion:
            return m.normalizer.unbias(m.net(cond)).unsqueeze(1)
        K = noise.shape[0] // B
        code = m.net.encode(cond).repeat_interleave(K, dim=0)
        nz = m.normalizer
        lo, hi = m.released_clip()
        clip_x0 = m.x0_clip()
        x = noise
        for t in self.timesteps:
            eps = m.net.denoise(x, torch.full((x.shape[0],), t, dtype=torch.int64, device=x.device), code)
            if self.sampler is Sampler.DDIM:
                x = m.scheduler.ddim_step(eps, t, x, clip_x0=clip_x0)
            else:
                x = m.scheduler.released_step(eps, t, x, lo, hi)
        return nz.unbias(x).reshape(B, K, T, IMU_CHANNELS)


def example_inputs(module: ExportedSampler, window_samples: int, k: int = 3) -> tuple[torch.Tensor, ...]:
    """Tracing inputs: 2 windows (and ``k`` samples each for a diffusion model)."""
    imu = torch.randn(2, window_samples, module.model.config.condition_channels)
    return (imu, torch.randn(2 * k, window_samples, IMU_CHANNELS)) if module.diffusion else (imu,)


def write_export(module: ExportedSampler, example: tuple[torch.Tensor, ...], path: str | Path,
                 fmt: ExportFormat | str) -> None:
    """Trace ``module`` on ``example`` and save it as TorchScript or ONNX at ``path`` (not atomic).

    Raises:
        ExportError: ONNX asked and the 'onnx' package is missing.
    """
    fmt = ExportFormat(fmt)
    with torch.no_grad(), warnings.catch_warnings():
        # the sampler's clip range and timesteps are constants of the graph, as the tracer warns
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        if fmt is ExportFormat.TORCHSCRIPT:
            # saved to memory, then written by Python: torch's own file writer aborts the process (a C++
            # exception in a destructor) when the disk fills, where Python's write raises ENOSPC
            buffer = io.BytesIO()
            torch.jit.save(torch.jit.trace(module, example, check_trace=False), buffer)
            Path(path).write_bytes(buffer.getvalue())
            return
        try:
            import onnx  # noqa: F401
        except ImportError:
            raise ExportError("ONNX export needs the 'onnx' package", path=path,
                              hint="pip install onnx onnxruntime (pinned in requirements.lock)") from None
        names = ["imu", "noise"] if module.diffusion else ["imu"]
        axes = {"imu": {0: "windows"}, "bias": {0: "windows", 1: "samples"}}
        if module.diffusion:
            axes["noise"] = {0: "windows_x_samples"}
        torch.onnx.export(module, example, str(path), input_names=names, output_names=["bias"],
                          dynamic_axes=axes, opset_version=ONNX_OPSET, dynamo=False)


def export_run(checkpoint: str | Path, out_path: str | Path, fmt: ExportFormat | str, *,
               sampler: Sampler | str = Sampler.DDIM, steps: int = STEPS) -> Path:
    """Export a trained run (rebuilt from its checkpoint) with its sampler; written atomically.

    Raises:
        CheckpointError: Unreadable checkpoint.
        ConfigError: DDPM sampler.
        ExportError: The exporter fails (e.g. onnx is not installed).
    """
    from training.fit.checkpoint import load_run

    fmt = ExportFormat(fmt)
    run = load_run(checkpoint, device="cpu")
    module = ExportedSampler(run.model, Sampler(sampler), steps).eval()
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        write_export(module, example_inputs(module, int(run.dataset["window_samples"])), tmp, fmt)
    log.info("exported %s (%s, %s sampler, %d steps) to %s", run.config.method, fmt.value,
             Sampler(sampler).value if module.diffusion else "no", steps, out)
    return out


def onnx_session(path: str | Path, threads: int | None = None):
    """An onnxruntime CPU session of an exported file (``threads``: intra-op threads)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
