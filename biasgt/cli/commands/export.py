"""``biasgt export``: a trained model with its sampler as TorchScript or ONNX (adapter over training.deploy.export)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.files.atomic import OutputKind

DESCRIPTION = """\
Export a trained model (rebuilt from its checkpoint) together with its sampler as one graph, for
deployment without biasgt: TorchScript (torch.jit) or ONNX (run it with onnxruntime).

A diffusion model's graph takes 'imu' [B, T, 6] (raw gyro rad/s then acc m/s^2, T = the model's window
length) and 'noise' [B*K, T, 6] (standard normal: the initial x_T of the K samples of each window) and
returns 'bias' [B, K, T, 6] (rad/s, m/s^2); the sampler (--sampler, --steps) is fixed in the graph,
so the same noise gives the same samples as PyTorch. A regression or indirect model takes 'imu' and
returns 'bias' [B, 1, T, 6].
"""

EPILOG = """\
examples:
  biasgt export --checkpoint results/training/diffusion_rnn/seed0 --format onnx --out diffusion_rnn.onnx
  biasgt export --checkpoint run --format torchscript --sampler released --out released.pt
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    from training.config import STEPS, ExportFormat, Sampler

    p = subparsers.add_parser("export", help="export a trained model with its sampler (TorchScript or ONNX)",
                              description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", required=True, type=Path, metavar="RUN", help="run folder (best.pt) or .pt file")
    p.add_argument("--format", required=True, choices=[f.value for f in ExportFormat], help="file format")
    p.add_argument("--out", required=True, type=Path, metavar="FILE", help="output file (written atomically)")
    p.add_argument("--sampler", default=Sampler.DDIM.value, choices=[Sampler.DDIM.value, Sampler.RELEASED.value],
                   help="sampler of a diffusion model (default ddim)")
    p.add_argument("--steps", type=int, default=STEPS, metavar="N", help=f"denoising steps (default {STEPS})")
    p.set_defaults(func=run, out_kind=OutputKind.FILE)


def run(args: argparse.Namespace) -> int:
    from training.deploy.export import export_run

    out = export_run(args.checkpoint, args.out, args.format, sampler=args.sampler, steps=args.steps)
    print(f"wrote {out}")
    return 0
