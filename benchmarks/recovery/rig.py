"""Rig imperfections over many seeds, on the project's simulator and on the independent generator, with defaults.

    .venv/bin/python benchmarks/recovery/rig.py [--seeds 20] [--duration 120] [--scenarios clean mems ...]
        [--generators sim independent] [--out records.jsonl] [--no-validate] [--summary-only]
        [--set KEY=VALUE ...]

Per generator (``sim``: :mod:`pipeline.sim`; ``independent``: ``tests/independent.py``, closed-form motion
and its own IMU, mocap and writer code) and seed, one recording per scenario, written as an EuRoC folder
without ground truth, read back, recovered with the default ``RecoveryConfig`` and validated with the
default ``ValidationConfig`` (the held-out blocks of the cross-validation judge):

* ``clean``: a calibrated IMU with a bias (turn-on + random walk), 100-Hz mocap 0.5 mm / 0.5 mrad;
* ``mems``: the same with random intrinsic errors per seed at a size factor ``u`` uniform in [0.25, 1]
  of gyro scale 1 %, 0.5 deg on every off-diagonal term of the gyro matrix (its rotation part
  included), accelerometer scale 0.5 %, g-sensitivity 2e-4 rad/s per m/s^2 (the independent
  generator draws each term uniform in [u/2, u] of its size with a random sign; the simulator draws
  Gaussians of sigma u/2 of the size);
* ``mocap_gm``: a unit with no bias at all; the mocap attitude carries a first-order Gauss-Markov error
  (2-6 mrad per axis, 0.3-3 s correlation time), at 100-120 Hz, with 3 dropouts of 0.5-1 s;
* ``tilt``: the mocap world frame tilted 0.5 deg from gravity (random azimuth).

Printed per generator, scenario and axis: the median bias RMSE and its ratio to the clean scenario's, the
NEES (mean squared error over sigma at the keyframes) mean and 95th percentile over seeds, the verdict
counts, and the checks: mean per-axis NEES in [0.5, 2]; no PASS with an axis' NEES above 4; at least
90 % of recordings with every axis' NEES at most 4; a unit with no bias FAILs on at most 5 % of seeds.
The NEES judged is the labels': the recovered sigma times the validation's held-out factor
(``heldout.sigma_check.factor``, 1 where the check confirmed it), as the window dataset carries it
(:mod:`training.data.windows`); the recovery's own sigma's NEES is printed beside it.

Each recording's figures are appended to ``--out`` (JSON lines; a rerun skips the recordings already
there), so a long sweep can run in the background and be summarised at any time (``--summary-only``).
``--set`` replaces recovery options (``RecoveryConfig`` fields, YAML values, e.g.
``random_walk_scales=[0.01,0.03,0.1,0.3,1,3,10,30,100,300]``) for the recovery and its held-out folds; a
record keeps its options, and a run summarises and resumes only the records of its own.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import independent as ind  # noqa: E402

AXES = ("gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z")
SCENARIOS = ("clean", "mems", "mocap_gm", "tilt")
GENERATORS = ("sim", "independent")
#: The MEMS case's full-size intrinsics: gyro scale, misalignment (deg), acc scale, g-sensitivity (rad/s per m/s^2).
MEMS_SIZES = dict(gyro_scale=0.01, misalignment_deg=0.5, acc_scale=0.005, g_sensitivity=2e-4)
TILT_DEG = 0.5
#: The goals: the mean NEES within MEAN_NEES_BOUNDS (judged per axis, and over the six axes: both printed);
#: every axis at most NEES_BOUND on WITHIN_SHARE of the recordings.
MEAN_NEES_BOUNDS = (0.5, 2.0)
NEES_BOUND = 4.0
WITHIN_SHARE = 0.9


def draws(scenario: str, seed: int) -> dict:
    """The scenario's random settings for ``seed`` (the same for both generators)."""
    rng = np.random.default_rng([seed, SCENARIOS.index(scenario), 40_2026])
    if scenario == "mems":
        return {"size": float(rng.uniform(0.25, 1.0))}
    if scenario == "mocap_gm":
        return {"sigma_rad": float(rng.uniform(2e-3, 6e-3)), "tau_s": float(rng.uniform(0.3, 3.0)),
                "rate_hz": float(rng.uniform(100.0, 120.0))}
    if scenario == "tilt":
        az = rng.uniform(0.0, 2 * np.pi)
        tilt = np.radians(TILT_DEG)
        return {"gravity_mps2": (9.81 * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az),
                                                  -np.cos(tilt)])).tolist()}
    return {}


def dropouts(duration_s: float, seed: int) -> tuple[tuple[float, float], ...]:
    """Three gaps of 0.5-1 s, one in each third of the recording (away from its ends)."""
    rng = np.random.default_rng([seed, 99, 40_2026])
    third = duration_s / 3
    return tuple((float(third * i + rng.uniform(0.1, 0.8) * third), float(rng.uniform(0.5, 1.0))) for i in range(3))


def write_sim(root: Path, scenario: str, seed: int, duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A :mod:`pipeline.sim` recording at ``root`` (no ground truth); ``(t_ns, bias_gyro, bias_acc)`` truth."""
    import shutil

    from pipeline.sim import SimConfig, simulate
    from pipeline.sim.config import ImuNoiseConfig, MotionConfig, PoseStreamConfig, TemperatureConfig
    from pipeline.sim.writer import write_simulation

    d = draws(scenario, seed)
    imu, motion, poses = {}, {}, {"extrinsic_known": True}
    if scenario == "mems":
        u = d["size"] / 2
        imu = dict(gyro_scale_sigma=u * MEMS_SIZES["gyro_scale"], acc_scale_sigma=u * MEMS_SIZES["acc_scale"],
                   gyro_misalignment_sigma=np.radians(u * MEMS_SIZES["misalignment_deg"]),
                   gyro_g_sensitivity_sigma=u * MEMS_SIZES["g_sensitivity"])
    elif scenario == "mocap_gm":
        imu = dict(turn_on_bias=False, bias_random_walk=False, temperature=TemperatureConfig(enabled=False))
        gaps = dropouts(duration_s, seed)
        poses.update(rate_hz=d["rate_hz"], correlated_rotation_noise_rad=d["sigma_rad"],
                     correlated_noise_tau_s=d["tau_s"], dropouts=len(gaps), dropout_max_s=1.0)
    elif scenario == "tilt":
        motion = dict(gravity_mps2=tuple(d["gravity_mps2"]))
    sim = simulate(SimConfig(duration_s=duration_s, seed=seed, imu=ImuNoiseConfig(**imu),
                             motion=MotionConfig(**motion), poses=PoseStreamConfig(**poses)))
    write_simulation(sim, root)
    shutil.rmtree(root / "mav0" / "state_groundtruth_estimate0")
    t = sim.truth
    return t.t_ns, t.bias_gyro_radps, t.bias_acc_mps2


def write_independent(root: Path, scenario: str, seed: int, duration_s: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An independent-generator recording at ``root`` (no ground truth); ``(t_ns, bias_gyro, bias_acc)`` truth."""
    d = draws(scenario, seed)
    kw: dict = {}
    if scenario == "mems":
        u, s = d["size"], MEMS_SIZES
        kw["intrinsics"] = ind.draw_intrinsics(
            seed, gyro_scale=(u * s["gyro_scale"] / 2, u * s["gyro_scale"]),
            misalignment_deg=(u * s["misalignment_deg"] / 2, u * s["misalignment_deg"]),
            acc_scale=(u * s["acc_scale"] / 2, u * s["acc_scale"]), g_sensitivity=u * s["g_sensitivity"])
    elif scenario == "mocap_gm":
        kw = dict(gyro_turn_on_sigma=0.0, acc_turn_on_sigma=0.0, gyro_random_walk=0.0, acc_random_walk=0.0,
                  pose_rate_hz=d["rate_hz"], correlated_rotation_noise_rad=d["sigma_rad"],
                  correlated_noise_tau_s=d["tau_s"], dropouts_s=dropouts(duration_s, seed))
    elif scenario == "tilt":
        kw["gravity_mps2"] = np.array(d["gravity_mps2"])
    seq = ind.make_sequence(duration_s, seed=seed, **kw)
    ind.write_euroc(seq, root, extrinsic_known=True, with_ground_truth=False)
    return seq.t_ns, seq.bias_gyro_radps, seq.bias_acc_mps2


def run_one(generator: str, scenario: str, seed: int, duration_s: float, validate: bool, tmp: Path,
            options: dict | None = None) -> dict:
    """Recover (and validate) one recording with defaults, or ``options`` (``RecoveryConfig`` fields); its figures
    against the truth as a JSON-able dict."""
    from pipeline.io import load_sequence
    from recovery.config import RecoveryConfig
    from recovery.recover import recover, write_recovery

    root = tmp / f"{generator}_{scenario}_{seed}"
    t_ns, bg, ba = (write_sim if generator == "sim" else write_independent)(root, scenario, seed, duration_s)
    seq = load_sequence(root)
    t0 = time.perf_counter()
    res = recover(seq, config=RecoveryConfig.from_dict(options or {}))
    rec = {"generator": generator, "scenario": scenario, "seed": seed, "duration_s": duration_s,
           "draws": draws(scenario, seed), "recover_s": time.perf_counter() - t0}
    if options:
        rec["options"] = options
    truth = [np.column_stack([np.interp(res.t_ns, t_ns, b[:, c]) for c in range(3)]) for b in (bg, ba)]
    err = np.hstack([res.bias_gyro_radps - truth[0], res.bias_acc_mps2 - truth[1]])
    std = np.hstack([res.bias_gyro_std_radps, res.bias_acc_std_mps2])
    rec["rmse"] = np.sqrt((err**2).mean(0)).tolist()
    rec["intrinsics_estimated"] = bool((res.report.get("intrinsics_auto") or {}).get("estimated", False))
    rec["nees"] = ((err / std) ** 2).mean(0).tolist()
    level = (res.report.get("gravity") or {}).get("level_test") or {}
    rec["gravity"] = {k: level.get(k) for k in ("tilt_deg", "tilt_sigmas", "level")}
    if validate:
        from validation.validate import validate_inputs

        rec_dir = write_recovery(res, tmp / f"rec_{generator}_{scenario}_{seed}")
        t1 = time.perf_counter()
        val = validate_inputs(seq, recovery_dir=rec_dir)
        rec.update(verdict=val.verdict.value, reason_codes=list(val.reason_codes), validate_s=time.perf_counter() - t1)
        check = (val.heldout or {}).get("sigma_check")
        if check:  # the labels' NEES: the sigma widened by the held-out check's factors (training.data.windows)
            rec["sigma_factor"] = check["factor"]
            rec["nees_widened"] = (np.array(rec["nees"]) / np.array(check["factor"]) ** 2).tolist()
    return rec


# ----------------------------------------------------------------------------- summary


def _row(label: str, values, fmt: str = "{:9.2e}") -> str:
    return f"    {label:28s}" + " ".join(fmt.format(v) for v in values)


def summarise(records: list[dict]) -> list[str]:
    """The printed table (module docstring) of ``records``."""
    lines = []
    for gen in GENERATORS:
        clean = [r for r in records if r["generator"] == gen and r["scenario"] == "clean"]
        clean_rmse = np.median([r["rmse"] for r in clean], axis=0) if clean else None
        for scen in SCENARIOS:
            every = [r for r in records if r["generator"] == gen and r["scenario"] == scen]
            rs = [r for r in every if "error" not in r]
            refused = len(every) - len(rs)
            if refused:
                lines.append(f"  {gen} / {scen}: {refused} of {len(every)} recordings refused by the recovery: "
                             + "; ".join(sorted({r['error'][:120] for r in every if 'error' in r})))
            if not rs:
                continue
            rmse = np.array([r["rmse"] for r in rs])
            nees = np.array([r.get("nees_widened", r["nees"]) for r in rs])  # the labels' sigma
            verdicts = [r.get("verdict") for r in rs]
            counts = {v: verdicts.count(v) for v in ("PASS", "WARN", "FAIL") if v in verdicts}
            worst = nees.max(1)
            lines.append(f"  {gen} / {scen}: {len(rs)} seeds, {rs[0]['duration_s']:g} s; recovery "
                         f"{np.median([r['recover_s'] for r in rs]):.0f} s median; verdicts {counts or 'not validated'}")
            lines.append("    " + " " * 28 + " ".join(f"{a:>9s}" for a in AXES))
            lines.append(_row("RMSE median", np.median(rmse, 0)))
            if clean_rmse is not None and scen != "clean":
                lines.append(_row("RMSE median / clean's", np.median(rmse, 0) / clean_rmse, "{:9.2f}"))
            lo, hi = MEAN_NEES_BOUNDS
            means = nees.mean(0)
            lines.append(_row(f"NEES mean ({lo:g}..{hi:g})", means, "{:9.2f}"))
            lines.append(_row("NEES 95th percentile", np.percentile(nees, 95, axis=0), "{:9.2f}"))
            pass_over = sum(1 for r, w in zip(rs, worst) if r.get("verdict") == "PASS" and w > NEES_BOUND)
            axes_out = int(np.sum((means < lo) | (means > hi)))
            over_axes = float(nees.mean())
            within = float(np.mean(worst <= NEES_BOUND))
            share = f"{100 * WITHIN_SHARE:.0f} %"
            checks = [f"mean NEES in [{lo:g}, {hi:g}]: each axis {'yes' if not axes_out else f'NO ({axes_out} out)'}, "
                      f"over the axes {over_axes:.2f} {'yes' if lo <= over_axes <= hi else 'NO'}",
                      f"PASS with an axis NEES > {NEES_BOUND:g}: {pass_over}",
                      f"all axes NEES <= {NEES_BOUND:g}: {100 * within:.0f} % "
                      f"({'ok' if within >= WITHIN_SHARE else 'below ' + share})"]
            if scen == "mocap_gm" and any(verdicts):
                fails = verdicts.count("FAIL")
                checks.append(f"no-bias FAILs {fails} of {len(rs)} ({'ok' if fails <= 0.05 * len(rs) else 'over 5 %'})")
            lines.append("    checks: " + "; ".join(checks))
            flagged = sum(1 for r in rs if "SIGMA_NOT_CONFIRMED" in (r.get("reason_codes") or []))
            over = int(np.sum(worst > NEES_BOUND))
            caught = sum(1 for r, w in zip(rs, worst) if w > NEES_BOUND and "SIGMA_NOT_CONFIRMED" in
                         (r.get("reason_codes") or []))
            lines.append(f"    SIGMA_NOT_CONFIRMED on {flagged} of {len(rs)}; of the {over} with an axis NEES > 4, "
                         f"{caught} flagged")
            own = np.array([r["nees"] for r in rs])
            lines.append(_row("recovery's sigma: NEES mean", own.mean(0), "{:9.2f}"))
            lines.append(f"    recovery's sigma: all axes NEES <= 4 on {100 * np.mean(own.max(1) <= NEES_BOUND):.0f} %")
    return lines


def read_records(path: Path) -> list[dict]:
    """The records of a ``--out`` file (none when it does not exist).

    Raises:
        ValueError: A line is not a record, named by ``path:line``.
    """
    if not path.exists():
        return []
    records = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            if not {"generator", "scenario", "seed"} <= record.keys():
                raise ValueError("no generator, scenario or seed")
        except (ValueError, AttributeError) as exc:
            raise ValueError(f"{path}:{number}: not a rig.py record ({exc}); pass a rig.py --out file") from None
        records.append(record)
    return records


def main(argv: list[str] | None = None) -> int:
    from pipeline.configs import assignments_to_mapping
    from pipeline.errors import BiasgtError
    from recovery.config import RecoveryConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="seeds per scenario and generator (0..N-1)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=120.0, help="recording length, s")
    ap.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    ap.add_argument("--generators", nargs="+", choices=GENERATORS, default=list(GENERATORS))
    ap.add_argument("--out", type=Path, default=None, help="JSON-lines file of the per-recording figures (resumed)")
    ap.add_argument("--no-validate", action="store_true", help="recover only (no verdicts)")
    ap.add_argument("--summary-only", action="store_true", help="summarise --out without running")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="recovery options other than the defaults (RecoveryConfig fields, YAML values)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    try:
        options = assignments_to_mapping(args.set)
        RecoveryConfig.from_dict(options)
    except BiasgtError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    mine = json.dumps(options, sort_keys=True)
    try:
        stored = read_records(args.out) if args.out else []
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    records = [r for r in stored
               if json.dumps(r.get("options", {}), sort_keys=True) == mine]
    done = {(r["generator"], r["scenario"], r["seed"], r["duration_s"]) for r in records}
    if not args.summary_only:
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                for gen in args.generators:
                    for scen in args.scenarios:
                        if (gen, scen, seed, args.duration) in done:
                            continue
                        try:
                            rec = run_one(gen, scen, seed, args.duration, not args.no_validate, Path(tmp), options)
                        except BiasgtError as exc:  # a refusal is a result: counted, not a crash
                            rec = {"generator": gen, "scenario": scen, "seed": seed, "duration_s": args.duration,
                                   "draws": draws(scen, seed), "error": str(exc),
                                   **({"options": options} if options else {})}
                        records.append(rec)
                        print(f"[{gen} {scen} seed {seed}] " + (f"refused: {rec['error']}" if "error" in rec else
                              f"NEES {np.round(rec['nees'], 2).tolist()} verdict {rec.get('verdict')} "
                              f"{rec.get('reason_codes', '')} ({rec['recover_s']:.0f} + {rec.get('validate_s', 0):.0f} s)"),
                              flush=True)
                        if args.out:
                            with open(args.out, "a", encoding="utf-8") as fh:
                                fh.write(json.dumps(rec) + "\n")
    keep = [r for r in records if r["duration_s"] == args.duration and r["generator"] in args.generators
            and r["scenario"] in args.scenarios]
    print("\n".join(summarise(keep)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
