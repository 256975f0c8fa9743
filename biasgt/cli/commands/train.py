"""``biasgt train``: train one bias model on a window dataset (adapter over training.fit.train)."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

from pipeline.files.atomic import OutputKind

log = logging.getLogger(__name__)


DESCRIPTION = """\
Train a model that predicts IMU bias from IMU readings, on a window dataset from 'biasgt windows'.
Reads the train split (training) and the validation split (best checkpoint); never the test split.

Methods (the registered networks, training.networks):
{methods}
Presets: paper (the released sizes, 2.2M / 42.8M parameters; for a GPU), small (CPU), tiny (tests).

Writes RUN/last.pt (every checkpoint_every steps and at the end), RUN/best.pt (lowest validation loss),
RUN/metrics.csv (step, train_loss, val_loss, lr, seconds) and RUN/run.json, each atomically.
--resume continues from RUN/last.pt and gives exactly the weights of an uninterrupted run. Every option
(lr, batch_size, ema_decay, val_every, use_temperature, ...) can be set in --config FILE.yaml (a mapping
of training options, or a file with a 'training:' section); command-line flags override it.
"""

EPILOG = """\
examples:
  biasgt train --dataset results/windows --method {m} --out runs/{m}
  biasgt train --dataset ds --method {m} --preset tiny --max-steps 200 --out runs/tiny
  biasgt train --dataset ds --method {m} --out runs/d --resume
  torchrun --nproc-per-node 2 -m biasgt.cli train --dataset ds --method {m} --out runs/ddp
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    from training.config import Preset, TrainConfig
    from training.networks import get_network, network_names

    methods = network_names()
    presets = [p.value for p in Preset]
    listing = "\n".join(f"  {m}: {get_network(m).help}" for m in methods)
    p = subparsers.add_parser(
        "train",
        help="train a bias model (diffusion, regression, indirect) on a window dataset",
        description=DESCRIPTION.format(methods=listing),
        epilog=EPILOG.format(m=TrainConfig().method),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--dataset", required=True, type=Path, metavar="DIR", help="window dataset ('biasgt windows')")
    p.add_argument("--method", choices=methods, metavar="METHOD",
                   help=f"one of {', '.join(methods)} (default {TrainConfig().method})")
    p.add_argument("--out", required=True, type=Path, metavar="RUN", help="run folder")
    p.add_argument("--config", type=Path, metavar="FILE", help="YAML with training options")
    p.add_argument("--preset", choices=presets, metavar="P",
                   help=f"network size: {', '.join(presets)} (default {TrainConfig().preset.value})")
    p.add_argument("--resume", action="store_true", help="continue from RUN/last.pt")
    p.add_argument("--max-steps", type=int, metavar="N", help="optimiser steps")
    p.add_argument("--seed", type=int, metavar="S", help="random seed")
    p.add_argument("--device", metavar="DEV", help="auto (default), cpu, cuda or cuda:N")
    p.add_argument("--threads", type=int, metavar="N", help="CPU threads (default: one per core)")
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def _read_config(path: Path) -> dict:
    import yaml

    from pipeline.errors import ConfigError

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read training options ({exc.__class__.__name__})", path=path,
                          hint="give a readable YAML mapping of training options") from None
    if isinstance(data, dict) and isinstance(data.get("training"), dict):
        data = data["training"]
    if not isinstance(data, dict):
        raise ConfigError("training options must be a mapping", path=path, hint="write 'option: value' lines")
    return data


def run(args: argparse.Namespace) -> int:
    from training.config import TrainConfig
    from training.fit.train import train

    options = _read_config(args.config) if args.config else {}
    for key, value in (("method", args.method), ("preset", args.preset), ("max_steps", args.max_steps),
                       ("seed", args.seed), ("device", args.device), ("threads", args.threads)):
        if value is not None:
            options[key] = value
    config = TrainConfig.from_mapping(options, path=args.config)
    out = train(config, args.dataset, args.out, resume=args.resume)
    if os.environ.get("RANK", "0") != "0":
        return 0  # under torchrun, rank 0 reports
    summary = out / "run.json"
    if summary.is_file():
        import json

        s = json.loads(summary.read_text(encoding="utf-8"))
        print(f"{s['method']} ({s['preset']}, {s['parameters']} parameters): {s['steps']} steps in "
              f"{s['train_seconds']:.1f} s ({s['windows_per_s']} windows/s); best validation loss "
              f"{s['best_val_loss']:.5g} at step {s['best_step']}")
    print(f"wrote {out}")
    return 0
