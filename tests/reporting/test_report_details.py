"""Report details: one number format, units without offsets, named residuals, the truth called the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biasgt.cli.commands.recover import outlier_counts
from reports import plots
from reports.quality import dataset_bias_label, mm_pair, verdict_summary
from validation.validate import said_once


def test_distances_side_by_side_share_one_format() -> None:
    assert mm_pair(0.930, 5.68) == ("930", "5680")
    assert mm_pair(0.0021, 0.0412) == ("2.10", "41.20")
    validation = {"verdict": "WARN", "candidate": "recovered", "sources": {
        "recovered": {"kind": "recovered", "prmse_m": 0.930, "roe_deg": 1.0},
        "constant": {"kind": "constant_first_window", "prmse_m": 5.68, "roe_deg": 2.0},
        "dataset": {"kind": "dataset", "prmse_m": 1.2, "roe_deg": 2.0}}}
    _, sentence = verdict_summary(validation, "the simulator's true bias")
    assert "PRMSE 930 mm vs 5680 mm" in sentence and "e+" not in sentence
    assert "dataset's own" not in sentence
    # fitted to these poses, the recovered bias integrates below the truth in-sample: not "better than" it
    assert "better than the simulator's true bias" not in sentence
    assert "as well as the simulator's true bias (930 mm vs 1200 mm: a bias fitted to these poses absorbs" in sentence
    _, own = verdict_summary(validation, "the dataset's own bias")
    assert "22% better than the dataset's own bias" in own  # another estimate, not the truth: compared as such


def test_numbers_read_with_sensible_precision_and_units() -> None:
    from reports.html import code_and_words, code_words, fmt_unc
    from reports.quality_calibration import scale_words
    from reports.quality_inputs import better_worse, relative_cell
    from reports.quality_residuals import reference_words

    assert fmt_unc(-7.376, 15.2, "ms") == "-7 ± 15 ms"  # rounded to the uncertainty's two digits
    assert fmt_unc(2.1, 0.3, "ms") == "2.10 ± 0.30 ms"
    assert fmt_unc(30.0, 0.0, "ms") == "30 ms (fixed)"  # set, not estimated: no "± 0"
    assert better_worse(1.471, 0.01) == "with 147 times the error of"  # not "14610% worse than"
    assert better_worse(0.012, 0.010) == "20% worse than" and better_worse(0.008, 0.010) == "20% better than"
    assert relative_cell(1.471, 0.01) == "147× (worse)" and relative_cell(0.008, 0.010) == "-20.0 %"
    assert code_words("bias_not_covered:recovered") == "bias not covered (recovered)"
    assert code_and_words("imu_gap") == 'imu gap <code class="rule">imu_gap</code>'  # the code kept for search
    assert reference_words({"kind": "state"}).startswith("the dataset's ground-truth state")
    assert reference_words({"kind": "poses", "stream": "vicon0"}) == "the pose stream 'vicon0' (kind 'poses')"
    assert scale_words(10.2) == "10.2× the calibration's (larger than calibrated)"
    assert scale_words(1.0) == "1× the calibration's (as calibrated)"
    from reports.quality_calibration import _vec_to

    # the extrinsic in mm beside its sigma in mm, no more digits than the sigma allows
    assert _vec_to([-0.0006543, 0.0002009, 0.0009333], [0.0007, 0.00065, 0.00092], 1e3) == "[-0.65, 0.20, 0.93]"
    assert _vec_to([0.1, 0.2, 0.3], None, 1e3) == "[100, 200, 300]"


def test_the_intrinsics_clause_says_not_checked_once() -> None:
    from recovery.intrinsics.report import intrinsics_clause

    clause = intrinsics_clause({"intrinsics_auto": {"estimated": False, "reason": "not checked: the rate coupling "
                                                    "needs at least 40 s of overlap, got 39.9 s"}})
    assert "(not checked: the rate coupling needs" in clause and "not estimated: not checked" not in clause


def test_a_simulated_recording_calls_its_bias_the_truth(tmp_path: Path, shared_data: Path) -> None:
    from biasgt.cli.app import main
    from pipeline.io import load_sequence

    assert main(["-q", "simulate", "--duration", "3", str(tmp_path / "sim")]) == 0
    assert dataset_bias_label(load_sequence(tmp_path / "sim")) == "the simulator's true bias"
    real = load_sequence(shared_data / "euroc" / "MH_04_difficult")
    assert dataset_bias_label(real) == "the dataset's own bias"


def test_a_next_step_is_said_once() -> None:
    short = "check the IMU noise values of the calibration (sensor.yaml: random walks)"
    longer = short + "; widen recovery.random_walk_scales only if the calibration is known to be wrong"
    assert said_once([short, "other", longer, "other"]) == ["other", longer]


def test_residual_panels_are_named_with_units_and_outliers_are_lines_on_every_panel() -> None:
    """A rejected pose has no pose residual (NaN): its mark is a vertical line at its time on every panel."""
    t = np.linspace(0, 10, 50)
    outliers = np.zeros(50, bool)
    outliers[[5, 20]] = True
    pose = np.ones(50)
    pose[outliers] = np.nan
    fig = plots.residual_series_figure(t, {"pose_whitened_rms": pose, "imu_whitened_rms": np.ones(50)}, outliers)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["pose residual\n[σ, whitened RMS]", "IMU residual\n[σ, whitened RMS]"]
    for ax in fig.axes:
        lines = [c for c in ax.collections if c.get_label() == "rejected as outlier"]
        xs = sorted(seg[0][0] for seg in lines[0].get_segments())
        assert len(lines) == 1 and np.allclose(xs, t[[5, 20]])  # not a 0/1 series, and seen on the pose panel


def test_bias_axes_carry_no_offset_label() -> None:
    t = np.linspace(0, 10, 100)
    bias = 2e-3 + 1e-5 * np.random.default_rng(0).standard_normal((100, 3))  # small values: an offset would show
    fig = plots.bias_figure(t, bias, np.full((100, 3), 1e-5), quantity="Gyroscope bias", unit="rad/s")
    fig.canvas.draw()
    assert all(ax.yaxis.get_offset_text().get_text() == "" for ax in fig.axes)


def test_recover_says_which_outlier_count_is_which() -> None:
    text = outlier_counts({"outliers_rejected": 4609, "keyframes": 1434, "pose_fusion": {"samples_rejected": 4400}})
    assert text == "outliers rejected: 209 of 1434 keyframe poses, 4400 pose samples before fusion"


def test_inspect_names_the_topics_it_cannot_use(shared_data: Path, capsys) -> None:
    from biasgt.cli.app import main

    bag = shared_data / "ros_bags" / "robot_localization_test" / "test1.bag"
    assert main(["inspect", str(bag)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if "TOPICS_NOT_USED" in x)
    assert "/fix (sensor_msgs/msg/NavSatFix, 989 msgs)" in line and "/imu/data" not in line


def test_allan_legend_names_where_the_calibration_came_from() -> None:
    """Datasheet defaults (no sensor.yaml given) are not labelled as a sensor.yaml."""
    from pipeline.types import ImuCalibration

    assert ImuCalibration().defaulted()  # nothing given: all four noise values are defaults
    taus = np.geomspace(0.01, 10.0, 20)
    adev = np.tile(1e-3 / np.sqrt(taus)[:, None], (1, 3))
    fig = plots.allan_figure(taus, adev, title="Gyroscope", unit="rad/s", white=np.full(3, 1e-3),
                             random_walk=np.full(3, 1e-5), sensor_white=2e-3, sensor_random_walk=2e-5,
                             sensor_label="default (EuRoC ADIS16448)")
    labels = [ln.get_label() for ln in fig.axes[0].lines]
    assert "default (EuRoC ADIS16448) white noise" in labels and not any("sensor.yaml" in x for x in labels)


def test_every_pose_source_kind_reads_in_plain_words() -> None:
    """The streams table says what a stream is: odometry (a wheel or VIO stream) is not labelled 'vio'."""
    from pipeline.types import PoseSourceKind
    from reports.quality_verdict import SOURCE_KIND_WORDS

    assert set(SOURCE_KIND_WORDS) == {k.value for k in PoseSourceKind}
    assert "wheel" in SOURCE_KIND_WORDS[PoseSourceKind.VIO.value]
