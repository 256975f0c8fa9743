"""Which labels train the better context model, judged three ways on real EuRoC.

Usage::

    .venv/bin/python benchmarks/learning/context_judges.py configs WORK       # WORK/labels_gt.yaml, WORK/test_vicon0.yaml
    biasgt run --config config/euroc.yaml     --until windows --directory WORK/a --cores 2
    biasgt run --config WORK/labels_gt.yaml   --until windows --directory WORK/b --cores 2
    biasgt run --config WORK/test_vicon0.yaml --until windows --directory WORK/v --cores 2
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/learning/context_judges.py run WORK [--seeds 0 1 2] [--steps 600]

``configs`` derives two workflow configs from ``config/euroc.yaml``: ``labels_gt.yaml`` recovers every
train sequence from its ground-truth poses (label set b), and ``test_vicon0.yaml`` recovers and judges
every test sequence that has a raw ``vicon0`` stream from that stream (its windows' start and end
states come from vicon0 through the recovery's clock offset and extrinsic).

``run`` trains one context variant (``--variant``, default ``filter_history_both``: the registered
context network with the variant's options, by ``biasgt train``'s trainer into ``WORK/runs``) per
seed on three label sets: (a) biasgt's labels of ``config/euroc.yaml`` (raw streams where a sequence
has one), (b) biasgt's labels from the ground-truth poses, (c) EuRoC's own bias where a sequence has
it, else (a) (:func:`training.data.dataset.with_state_labels`).
Each model, and the reference rows, are judged on the test split three ways:

* ``state``: EuRoC's ground-truth state (the paper's protocol);
* ``vicon0``: the raw Vicon stream, where a test sequence has one (EuRoC's state elsewhere);
* ``turned``: EuRoC's positions and velocities with its attitude turned by the constant IMU-frame
  rotation onto the vicon0 recovery's attitude (:func:`validation.attitude.reference_attitude_offset`).
  This separates an accelerometer offset across gravity that stands for a tilt of EuRoC's attitude
  from one of the IMU (printed: EuRoC's mean accelerometer bias less the train mean, across gravity,
  beside the bias that tilt stands for). Its ROE is not a judge (turning a relative rotation by an IMU-frame offset
  changes it), so only its PRMSE is printed.

Prints PRMSE m / ROE deg, averaged over the test sequences (mean +- std over the seeds) and per
sequence, and wall and CPU time. Exit code 0 (the figures are the output).
"""

from __future__ import annotations

import argparse
import copy
import os
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from pipeline.errors import BiasgtError  # noqa: E402
from pipeline.io import load_sequence  # noqa: E402
from pipeline.io.tum import read_tum_poses  # noqa: E402
from pipeline.types import DEFAULT_GRAVITY_MPS2, PoseSourceKind  # noqa: E402
from training.config import EvaluationConfig  # noqa: E402
from training.data.records import has_context, write_context  # noqa: E402
from training.data.dataset import read_manifest, with_state_labels  # noqa: E402
from training.evaluation.evaluate import evaluate_reference, evaluate_run  # noqa: E402
from validation.attitude import reference_attitude_offset  # noqa: E402
from validation.reference import reference_from_states  # noqa: E402

EUROC_CONFIG = REPO / "config" / "euroc.yaml"
REFERENCES = ("train_mean", "start_rest", "bias_filter", "sequence_mean", "state_bias")
#: Label set -> its dataset under WORK (c: a's windows labelled with EuRoC's bias where a sequence has it).
LABEL_SETS = {"a: raw streams": "a", "b: ground-truth poses": "b", "c: EuRoC's bias": "c"}
JUDGES = ("state", "vicon0", "turned")


# ----------------------------------------------------------------------------- configs


def derived_configs(base: dict, config_dir: Path) -> dict[str, dict]:
    """``labels_gt`` and ``test_vicon0`` (see the module docstring) from the config ``base`` read from
    ``config_dir``; ``data_root`` made absolute."""
    data_root = (config_dir / base["data_root"]).resolve()
    gt, vic = copy.deepcopy(base), copy.deepcopy(base)
    for cfg in (gt, vic):
        cfg["data_root"] = str(data_root)
    for entry in gt["sequences"]:
        if entry["split"] == "train":
            streams = [p["stream"] for p in entry.get("poses", []) if p.get("kind") == "ground_truth"]
            entry["recovery"] = {**entry.get("recovery", {}), "pose_stream": streams[0] if streams else "ground_truth"}
    for entry in vic["sequences"]:
        if entry["split"] == "test" and (data_root / entry["path"] / "mav0" / "vicon0").is_dir():
            entry["recovery"] = {**entry.get("recovery", {}), "pose_stream": "vicon0"}
            entry["validation"] = {**entry.get("validation", {}), "poses": "vicon0"}
    return {"labels_gt": gt, "test_vicon0": vic}


def write_configs(work: Path) -> None:
    work.mkdir(parents=True, exist_ok=True)
    for name, cfg in derived_configs(yaml.safe_load(EUROC_CONFIG.read_text()), EUROC_CONFIG.parent).items():
        (work / f"{name}.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        print(f"wrote {work / f'{name}.yaml'}")


# ----------------------------------------------------------------------------- judges


def turned_dataset(state_ds: Path, vicon_run: Path, out: Path, folders: dict[str, Path]) -> dict[str, dict]:
    """A copy of ``state_ds`` whose vicon0-judged test sequences (in ``vicon_run``'s dataset) take EuRoC's
    attitude turned onto the vicon0 recovery's; ``folders``: sequence -> its EuRoC folder. Returns
    each offset (deg)."""
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(state_ds, out)
    vman = read_manifest(vicon_run / "results" / "windows" / "dataset")
    manifest = read_manifest(out)
    offsets = {}
    for name in vman.names("test"):
        info = vman["sequences"][name].get("info") or {}
        if (info.get("reference_info") or {}).get("stream") != "vicon0":
            continue
        seq = load_sequence(folders[name])
        ours, _ = read_tum_poses(vicon_run / info["recovery_dir"] / "trajectory_tum.txt",
                                 source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
        off = reference_attitude_offset(reference_from_states(seq.ground_truth, seq.imu.t_ns), ours,
                                        np.asarray(DEFAULT_GRAVITY_MPS2))
        dR = Rotation.from_rotvec(np.radians(off.rotvec_deg)).as_matrix()
        for key in ("start_R", "end_R"):
            path = out / manifest.sequences[name].path / f"{key}.npy"
            R = np.load(path)
            np.save(path, (R @ dR).astype(R.dtype))
        offsets[name] = {"tilt_deg": off.tilt_deg, "heading_deg": off.heading_deg,
                         **_across_gravity(seq, np.radians(off.rotvec_deg), manifest)}
    return offsets


def _across_gravity(seq, rotvec_rad: np.ndarray, manifest) -> dict[str, np.ndarray]:
    """EuRoC's mean accelerometer bias less the train mean, and the bias a tilt of EuRoC's attitude by
    ``rotvec_rad`` stands for (R_state = R_ours Exp(-d): b_state - b_ours = -d x a, with a the mean
    specific force), both across gravity (m/s^2, IMU frame), [3] each."""
    a = seq.imu.acc_mps2.mean(axis=0)
    u = a / np.linalg.norm(a)

    def across(v: np.ndarray) -> np.ndarray:
        return v - (v @ u) * u

    euroc = seq.ground_truth.bias_acc_mps2.mean(axis=0) - np.asarray(manifest.normalization["bias_mean"])[3:]
    return {"euroc_minus_train_mean": across(euroc), "tilt_equivalent": across(-np.cross(rotvec_rad, a))}


def _per_sequence(summary) -> dict[str, tuple[float, float]]:
    return {s: (m.prmse_m, m.roe_deg) for s, m in summary.rows[0].sequences.items()}


def _fmt(runs: list[dict[str, tuple[float, float]]], judge: str) -> str:
    """``mean +- std`` of the seeds' averages, then each sequence's mean over the seeds."""
    avg = np.array([np.mean(list(r.values()), axis=0) for r in runs])  # [S, 2]
    names = list(runs[0])
    per = {s: np.mean([r[s] for r in runs], axis=0) for s in names}
    if judge == "turned":
        head = f"{avg[:, 0].mean():.4f} +- {avg[:, 0].std():.4f}"
        return head + "   " + "  ".join(f"{s[:5]} {v[0]:.4f}" for s, v in per.items())
    head = f"{avg[:, 0].mean():.4f} +- {avg[:, 0].std():.4f} / {avg[:, 1].mean():.4f} +- {avg[:, 1].std():.4f}"
    return head + "   " + "  ".join(f"{s[:5]} {v[0]:.4f}/{v[1]:.4f}" for s, v in per.items())


def run(work: Path, seeds: list[int], steps: int, variant: str) -> None:
    from context_euroc import VARIANTS, train_variant

    cfg = EvaluationConfig(samples=1, gravity="nominal")
    vicon_cfg = yaml.safe_load((work / "test_vicon0.yaml").read_text())
    folders = {e["name"]: Path(vicon_cfg["data_root"]) / e["path"] for e in vicon_cfg["sequences"]}
    datasets = {k: work / k / "results" / "windows" / "dataset" for k in ("a", "b", "v")}
    for key, ds in datasets.items():
        if not has_context(ds):
            write_context(ds, work / key)
    offsets = turned_dataset(datasets["a"], work / "v", work / "turned" / "dataset", folders)
    print("EuRoC's attitude turned onto the vicon0 recovery's; across gravity (IMU frame, m/s^2), EuRoC's mean "
          "accelerometer bias less the train mean beside the bias that tilt stands for:")
    for n, o in offsets.items():
        print(f"  {n[:5]} tilt {o['tilt_deg']:.2f} deg, heading {o['heading_deg']:.2f} deg; "
              f"{np.round(o['euroc_minus_train_mean'], 3)} beside {np.round(o['tilt_equivalent'], 3)}")
    judged = {"state": datasets["a"], "vicon0": datasets["v"], "turned": work / "turned" / "dataset"}
    datasets["c"] = with_state_labels(datasets["a"], work / "c" / "dataset")
    print("\nreference rows (train_mean etc. from label set a)")
    for judge, ds in judged.items():
        for ref in REFERENCES:
            try:
                print(f"  {judge:7s} {ref:14s} {_fmt([_per_sequence(evaluate_reference(ref, ds, None, cfg).summary)], judge)}")
            except BiasgtError as exc:
                print(f"  {judge:7s} {ref:14s} n/a ({exc.problem})")
    print(f"\n{variant}, {steps} steps, seeds {seeds}: PRMSE m / ROE deg (turned: PRMSE only)")
    method, options = VARIANTS[variant]
    for label, key in LABEL_SETS.items():
        runs: dict[str, list] = {j: [] for j in JUDGES}
        t, c = time.perf_counter(), time.process_time()
        for seed in seeds:
            run_dir = train_variant(datasets[key], method, options, work / "runs" / f"{key}_{variant}_seed{seed}",
                                    steps=steps, seed=seed)
            for judge, ds in judged.items():
                runs[judge].append(_per_sequence(evaluate_run(run_dir, ds, None, cfg, method=method).summary))
        for judge in JUDGES:
            print(f"  ({label:22s}) {judge:7s} {_fmt(runs[judge], judge)}")
        print(f"  {'':24s} [{time.perf_counter() - t:.0f} s wall, {time.process_time() - c:.0f} s CPU]", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("configs").add_argument("work", type=Path)
    p = sub.add_parser("run")
    p.add_argument("work", type=Path)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--variant", default="filter_history_both")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sys.path.insert(0, str(Path(__file__).parent))
    wall0, cpu0 = time.perf_counter(), time.process_time()
    if args.command == "configs":
        write_configs(args.work)
    else:
        run(args.work, args.seeds, args.steps, args.variant)
        print(f"\nwall {time.perf_counter() - wall0:.0f} s, CPU {time.process_time() - cpu0:.0f} s (1 thread)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
