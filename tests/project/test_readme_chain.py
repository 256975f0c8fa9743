"""The README's single-sequence chain runs as printed, on real data (EuRoC V1_02, first 40 s)."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from biasgt.cli.app import main

README = Path(__file__).resolve().parents[2] / "README.md"


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


def readme_line(command_start: str) -> list[str]:
    """The README command starting with ``command_start`` (continuation lines joined, comment dropped)."""
    text = re.sub(r"\\\n\s*", " ", README.read_text())
    line = next(x for x in text.splitlines() if x.startswith(command_start))
    return shlex.split(line.split("#")[0])


def test_euroc_v1_01_example_uses_the_added_poses_and_says_so(shared_data: Path, tmp_path: Path, monkeypatch,
                                                             capsys) -> None:
    """The README's EuRoC line as printed (its data/ is the shared EuRoC folder); then validate and report
    on the same raw input with the same --add-poses, as recover takes it."""
    (tmp_path / "data").symlink_to(shared_data / "euroc")
    monkeypatch.chdir(tmp_path)
    argv = readme_line("biasgt recover data/V1_01_easy")
    assert "--poses" not in argv
    assert main(argv[1:]) == 0
    out = capsys.readouterr().out
    assert out.startswith("pose stream: 'V1_01_easy_original' (given with --add-poses); also in the input: vicon0")
    assert json.loads((tmp_path / "out" / "V1_01" / "recovery.json").read_text())["pose_stream"] == "V1_01_easy_original"
    added = argv[argv.index("--add-poses") + 1]
    assert main(["validate", "data/V1_01_easy", "--add-poses", added, "--recovery", "out/V1_01", "--crossval", "off",
                 "--out", "out/V1_01/validation"]) in (0, 1)
    summary = json.loads((tmp_path / "out" / "V1_01" / "validation" / "validation.json").read_text())
    assert summary["plausibility"] == []  # a real recovery against its ground truth is possible
    capsys.readouterr()
    assert main(["report", "--ingest", "data/V1_01_easy", "--add-poses", added, "--recovery", "out/V1_01",
                 "--validation", "out/V1_01/validation", "--out", "out/V1_01/quality.html"]) == 0
    html = (tmp_path / "out" / "V1_01" / "quality.html").read_text()
    assert "V1_01_easy_original" in html and "implausible" not in html.split("<style>")[-1].split("</style>")[-1]


def test_workflow_example_of_the_readme_parses_as_printed(tmp_path: Path, capsys, shared_data) -> None:
    # the EuRoC config reads the real recordings: without them the dry run refuses its paths (skipped)
    argv = readme_line("biasgt run --config config/euroc.yaml")
    assert argv == ["biasgt", "run", "--config", "config/euroc.yaml", "--cores", "2"]
    assert main([*argv[1:], "--dry-run", "--directory", str(tmp_path)]) == 0
