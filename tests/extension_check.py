"""Run in a fresh interpreter by tests/project/test_plugins.py (the demo plugin installed) and tests/project/test_extension_guide.py
(a copy of the repository with the README's four recipes followed): a new reader, network, reference row and
verdict rule are in the CLI choices and help, the config check, the verdict and Table I, and ``--help`` loads no
torch. Arguments: a scratch folder and a JSON of the entries' names (:class:`Names`; default: the demo
plugin's). Exits 0 and prints "ok" when every check holds (an assertion error otherwise).

The entries do what the demo plugin's do (tests/plugin/biasgt_demo_plugin): a reader of ``t_ms,gx,gy,gz,ax_g,
ay_g,az_g`` CSV files, a linear regression network, a row of half the recovered bias, a rule that warns on a
recording shorter than a minute."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))


@dataclass(frozen=True)
class Names:
    """What the entries are called."""

    reader: str = "demo_ms_g"
    reader_help: str = "a demo IMU log"
    network: str = "demo_linear"
    network_label: str = "Demo linear"
    row: str = "demo_half_truth"
    row_label: str = "Half the GT bias (demo)"
    rule: str = "DEMO_SHORT_RECORDING"
    rule_help: str = "a recording shorter than a minute (demo)"
    rule_step: str = "record for a minute or more (demo)"


def choices(parser: argparse.ArgumentParser, command: str, option: str) -> list[str]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return list(next(a for a in sub.choices[command]._actions if option in a.option_strings).choices)


def help_text(main, argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main(argv)
    return " ".join(out.getvalue().split())


def main_check(work: Path, n: Names) -> None:
    work.mkdir(parents=True, exist_ok=True)
    from biasgt.cli.app import build_parser, main
    from biasgt.workflow.config import load_config
    from pipeline.io.registry import detect_format
    from pipeline.store import read_store
    from workflow_configs import sim_entry, write_config

    # no torch for the help, whatever the plugin's network imports
    help_text(main, ["evaluate", "--help"])
    assert "torch" not in sys.modules, "a plugin pulled torch into --help"
    # the CLI's choices and help
    parser = build_parser()
    assert choices(parser, "train", "--method")[-1] == n.network
    assert choices(parser, "evaluate", "--reference")[-1] == n.row
    assert f"{n.reader}: {n.reader_help}" in help_text(main, ["convert", "--help"])
    assert f"{n.rule} (WARN): {n.rule_help}" in help_text(main, ["validate", "--help"])
    # the reader: detected before csv, converted with the stamps in ns and the acc in m/s^2
    log = work / "log.csv"
    log.write_text("t_ms,gx,gy,gz,ax_g,ay_g,az_g\n" + "".join(f"{5.0 * i:.1f},0.01,-0.02,0.03,0.0,0.0,1.0\n"
                                                              for i in range(4000)), encoding="utf-8")
    assert detect_format(log) == n.reader
    assert main(["convert", str(log), "--out", str(work / "store")]) == 0
    back = read_store(work / "store")
    assert back.imu.t_ns[1] - back.imu.t_ns[0] == 5_000_000
    np.testing.assert_allclose(back.imu.acc_mps2[0], [0.0, 0.0, 9.80665])
    # the workflow's config check takes the reader as a source, the network and the row in a plan
    cfg = load_config(write_config(work / "plugin.yaml", {
        "sequences": [sim_entry("a"), {"name": "logger", "source": n.reader, "path": str(log)}],
        "training": {"methods": [n.network]}, "evaluation": {"references": ["zero", n.row]}}))
    assert cfg.sequence("logger").source == n.reader
    assert cfg.data["training"]["methods"] == [n.network]
    # the rule fires in the verdict
    validate_with_the_rule(work, n)
    # Table I: the network trained and evaluated, the row evaluated, in the registry's order
    table_with_the_network_and_row(work, n)


def validate_with_the_rule(work: Path, n: Names) -> None:
    from pipeline.bias_table import BiasTrack
    from pipeline.sim import SimConfig, simulate
    from validation.rules import next_steps_for
    from validation.validate import validate_sequence, write_validation

    sim = simulate(SimConfig(duration_s=8.0, seed=4).noise_free())
    b = np.hstack([sim.truth.bias_gyro_radps, sim.truth.bias_acc_mps2])
    res = validate_sequence(sim.sequence, {"recovered": BiasTrack(sim.truth.t_ns, b, np.zeros_like(b))},
                            gravity_mps2=sim.truth.gravity_mps2)
    assert res.reason_codes == [n.rule], res.reasons
    write_validation(res, work / "validation")
    data = json.loads((work / "validation" / "validation.json").read_text())
    assert data["verdict"] == "WARN" and data["reason_codes"] == [n.rule]
    assert next_steps_for(data["reason_codes"]) == [n.rule_step]
    assert "the recording lasts 8.0 s" in data["reasons"][0]


def table_with_the_network_and_row(work: Path, n: Names) -> None:
    import pandas as pd

    from training.config import EvaluationConfig, TrainConfig
    from training.evaluation.evaluate import evaluate_reference, evaluate_run
    from training.evaluation.table import TABLE_CSV, write_table
    from training.fit.train import train
    from window_data import make_window_dataset

    data = make_window_dataset(work, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    run = train(TrainConfig(method=n.network, preset="tiny", max_steps=3, batch_size=8, val_every=3,
                            checkpoint_every=3, warmup_steps=1, device="cpu", threads=1), data, work / "run")
    ev = work / "evaluation"
    evaluate_run(run, data, ev / n.network, EvaluationConfig(samples=2), method=n.network)
    rows = {r: evaluate_reference(r, data, ev / r).summary for r in ("zero", "ground_truth", n.row)}
    avg = {r: s.row().average.prmse_m for r, s in rows.items()}
    assert avg["ground_truth"] < avg[n.row] < avg["zero"], avg
    write_table([ev / name / "summary.json" for name in (n.row, "zero", n.network, "ground_truth")], ev)
    columns = [c.removesuffix(" PRMSE_m") for c in pd.read_csv(ev / TABLE_CSV, index_col=0).columns if
               c.endswith("PRMSE_m")]
    assert columns == [n.network_label, "Zero bias", "Recovered GT bias", n.row_label], columns


if __name__ == "__main__":
    main_check(Path(sys.argv[1]), Names(**json.loads(sys.argv[2])) if len(sys.argv) > 2 else Names())
    print("ok")
