"""The README's single-sequence chain runs as printed, on real data (EuRoC V1_02, first 40 s)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from pipeline.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_chain() -> list[list[str]]:
    """The commands of the README's "data engineer" block, continuation lines joined, comments dropped."""
    block = re.search(r"# A data engineer onboarding.*?\n(.*?)\n\n", README.read_text(), re.S).group(1)
    text = re.sub(r"\\\n\s*", " ", block)
    return [shlex.split(line.split("#")[0]) for line in text.splitlines() if line.strip() and not line.startswith("#")]


@pytest.mark.slow
def test_readme_chain_runs_as_printed_on_real_data(shared_data: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    recording = shared_data / "euroc" / "V1_02_medium_kimera_excerpt"
    monkeypatch.chdir(tmp_path)
    chain = readme_chain()
    assert [c[1] for c in chain] == ["inspect", "convert", "recover", "interpolate", "validate", "report", "windows"]
    for argv in chain:
        argv = [str(recording) if a == "my_recording.bag" else a for a in argv[1:]]
        rc = main(argv)
        out = capsys.readouterr()
        assert rc == 0, (argv, out.err[-2000:])
    assert (tmp_path / "out" / "rec01" / "quality.html").is_file()
    assert (tmp_path / "out" / "rec01" / "bias_imu.parquet").is_file()
    assert (tmp_path / "out" / "rec01" / "validation" / "validation.json").is_file()
    assert (tmp_path / "out" / "dataset" / "manifest.json").is_file()
