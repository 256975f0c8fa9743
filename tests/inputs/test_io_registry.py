"""The reader registry (:mod:`pipeline.io.registry`): a reader added with one ``register`` call is
found everywhere a format is listed or picked (CLI, workflow config, ``load_sequence``), and each
format's name lives in its registry entry and its implementation only."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from biasgt.cli.app import main
from biasgt.workflow.config import load_config
from biasgt.workflow.params import ingest_settings
from pipeline.errors import ConfigError
from pipeline.io import load_sequence
from pipeline.io.registry import (
    READERS,
    SOURCE_FORMAT_KEY,
    Reader,
    detect_format,
    parse_format,
    recorded_format,
    register,
    unregister,
)
from pipeline.store import read_store
from plugin.biasgt_demo_plugin import reader as demo_reader
from workflow_configs import write_config

REPO = Path(__file__).resolve().parents[2]

# A CSV dialect of some IMU logger: stamps in milliseconds, accelerometer in g, gyro in rad/s (the demo
# plugin's reader, registered here by hand).
DIALECT = "imu_ms_g"
HEADER, G0 = demo_reader.HEADER, demo_reader.G0
_detect, _load = demo_reader.detect, demo_reader.load


@pytest.fixture
def dialect(tmp_path: Path):
    """The dialect registered (before ASL, whose header sniffer is lenient) and a 40-s file of it at 200 Hz."""
    register(Reader(DIALECT, "an IMU log in ms and g", "an IMU log (t_ms, gyro rad/s, acc in g)",
                    load=_load, detect=_detect, aliases=("msg-imu",)), before="asl")
    t_ms = np.arange(8000) * 5.0  # 200 Hz
    path = tmp_path / "log.csv"
    lines = [HEADER] + [f"{t:.1f},0.01,-0.02,0.03,0.0,0.0,1.0" for t in t_ms]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    yield path
    unregister(DIALECT)
    assert DIALECT not in READERS


def test_registered_reader_is_detected_and_loaded(dialect: Path) -> None:
    assert detect_format(dialect) == DIALECT
    assert parse_format("MSG-IMU") == DIALECT
    for seq in (load_sequence(dialect), load_sequence(dialect, fmt=DIALECT)):
        assert seq.imu.t_ns[1] - seq.imu.t_ns[0] == 5_000_000  # 5 ms in ns
        np.testing.assert_allclose(seq.imu.acc_mps2[0], [0.0, 0.0, G0])
        np.testing.assert_allclose(seq.imu.gyro_radps[0], [0.01, -0.02, 0.03])
        assert seq.metadata[SOURCE_FORMAT_KEY] == DIALECT
    with pytest.raises(ConfigError, match="option imu_topic applies to bag input only"):
        load_sequence(dialect, imu_topic="/imu")


def test_registered_reader_in_the_cli(dialect: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    for command in ("convert", "inspect", "recover"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert f"{DIALECT}: an IMU log" in re.sub(r"\s+", " ", capsys.readouterr().out)
    assert main(["inspect", "--json", "--format", DIALECT, str(dialect)]) == 0
    assert json.loads(capsys.readouterr().out)["format"] == DIALECT
    store = tmp_path / "store"
    assert main(["convert", str(dialect), "--out", str(store)]) == 0
    back = read_store(store)
    assert recorded_format(back.metadata) == DIALECT and len(back.imu) == 8000
    np.testing.assert_allclose(back.imu.acc_mps2[-1], [0.0, 0.0, G0])


def test_registered_reader_is_a_workflow_source(dialect: Path, tmp_path: Path) -> None:
    entry = {"name": "logger", "source": DIALECT, "path": str(dialect)}
    cfg = load_config(write_config(tmp_path / "ok.yaml", {"sequences": [entry]}))
    assert cfg.sequence("logger").source == DIALECT
    assert ingest_settings(cfg, "logger")["reader_kwargs"]["fmt"] == DIALECT
    bad = write_config(tmp_path / "bad.yaml", {"sequences": [{**entry, "source": "imu_ms_x"}]})
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    kinds = ", ".join(["simulate", *(name for name, reader in READERS.items() if not reader.is_store)])
    assert DIALECT in kinds and "store" not in kinds
    assert f"sequences[0].source (sequence 'logger'): 'imu_ms_x' is not one of {kinds} (field 'source')" in str(info.value)


def test_without_the_dialect_its_name_is_unknown(tmp_path: Path) -> None:
    assert DIALECT not in READERS
    with pytest.raises(ConfigError, match="unknown input format"):
        parse_format(DIALECT)


def test_register_refuses_a_taken_name() -> None:
    with pytest.raises(ConfigError, match="rosbag already taken"):
        register(Reader("other", "x", "x", load=_load, aliases=("rosbag",)))
    with pytest.raises(ConfigError, match="no reader 'nope'"):
        register(Reader("other", "x", "x", load=_load), before="nope")
    assert "other" not in READERS


def test_recorded_format_reads_the_key_and_stores_written_before_it() -> None:
    assert recorded_format({SOURCE_FORMAT_KEY: "asl"}) == "asl"
    assert recorded_format({"source_kind": "rosbag"}) == "rosbag"  # bag stores written before the one key
    assert recorded_format({SOURCE_FORMAT_KEY: "tum", "source_kind": "x"}) == "tum"
    bag = {"source_kind": "rosbag", "bag": {"format": "rosbag2-mcap"}}
    assert recorded_format(bag) == "rosbag" and recorded_format(bag, variant=True) == "rosbag2-mcap"
    assert recorded_format({SOURCE_FORMAT_KEY: "asl", "bag": {"format": "rosbag1"}}, variant=True) == "asl"
    assert recorded_format({}) is None and recorded_format({SOURCE_FORMAT_KEY: 3}) is None


def _package_files() -> list[Path]:
    """The code of the package (the glue, stages, core and the Snakemake rules and scripts);
    tests, docs, configs and the schema aside."""
    roots = ["biasgt", "pipeline", "recovery", "interpolation", "validation", "training", "reports", "workflow"]
    files = [p for r in roots for p in (REPO / r).rglob("*") if p.suffix in (".py", ".smk")]
    return sorted([*files, REPO / "Snakefile"])


def test_each_format_name_lives_in_its_entry_and_its_implementation() -> None:
    files = _package_files()
    registry = REPO / "pipeline" / "io" / "registry.py"
    assert registry in files and len(files) > 50
    texts = {p: p.read_text(encoding="utf-8") for p in files}
    for name in READERS:
        literal = re.compile(rf"[\"']{re.escape(name)}[\"']")
        holders = [p.relative_to(REPO).as_posix() for p, text in texts.items() if literal.search(text)]
        assert "pipeline/io/registry.py" in holders and len(holders) <= 2, (name, holders)
