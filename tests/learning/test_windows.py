"""Training windows on the simulator: counts, contents, drops, rates, splits, manifest, loading, atomicity, CLI."""

from __future__ import annotations

import dataclasses
import json
import pickle
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from interpolation.bias import interpolate_bias
from pipeline.bias_table import BiasTrack, read_bias_csv
from recovery.outputs import read_report
from pipeline import __version__
from biasgt.cli.app import main
from pipeline.errors import ConfigError, DataError, InputFormatError
from pipeline.sim import ImuNoiseConfig, PoseStreamConfig, SimConfig, simulate
from pipeline.store import read_store, write_store
from pipeline.types import ImuSeries
from synth import write_recovery_folder
from training.data.dataset import ARRAYS, STATE_BIAS, TEMPERATURE, Split, WindowDataset, read_manifest
from training.data.windows import (
    WindowConfig,
    WindowSource,
    build_window_dataset,
    extract_windows,
    format_summary,
    read_splits_file,
    resample_imu,
    sources_from_results,
)

NS = 1_000_000_000
RW = (2e-4, 3e-3)  # gyro, acc random walks written to recovery.json


# ----------------------------------------------------------------------------- helpers


def _sim(seed: int = 1, duration_s: float = 10.0, rate_hz: float = 200.0, name: str = "sim", **kw):
    return simulate(SimConfig(duration_s=duration_s, seed=seed, name=name,
                              imu=ImuNoiseConfig(rate_hz=rate_hz), **kw))


def _write_recovery(folder: Path, sim, *, every: int = 10, span_s: tuple[float, float] | None = None,
                    offset_s: float = 0.0, T_imu_pose: np.ndarray | None = None) -> Path:
    """A recovery folder from the simulator's true bias: keyframes every ``every`` IMU samples."""
    tr = sim.truth
    k = np.arange(0, len(tr.t_ns), every)
    if span_s is not None:
        rel = (tr.t_ns[k] - tr.t_ns[0]) / NS
        k = k[(rel >= span_s[0] - 1e-9) & (rel <= span_s[1] + 1e-9)]
    bias = np.hstack([tr.bias_gyro_radps, tr.bias_acc_mps2])[k]
    std = 1e-4 * (1 + np.arange(6))[None, :] * (1 + 0.1 * np.sin(np.arange(len(k))))[:, None]
    T = np.eye(4) if T_imu_pose is None else T_imu_pose
    report = {
        "noise": {"gyro_random_walk": RW[0], "acc_random_walk": RW[1]},
        "gravity_world_mps2": [0.0, 0.0, -9.81],
        "pose_time_offset_s": offset_s,
        "T_imu_pose": {"p_m": T[:3, 3].tolist(),
                       "quat_wxyz": Rotation.from_matrix(T[:3, :3]).as_quat(scalar_first=True).tolist()},
    }
    return write_recovery_folder(folder, BiasTrack(tr.t_ns[k], bias, std), report)


def _source(tmp: Path, sim, name: str, split: str, **rec_kw) -> WindowSource:
    store = write_store(dataclasses.replace(sim.sequence, name=name), tmp / "stores" / name)
    rec = _write_recovery(tmp / "rec" / name, sim, **rec_kw)
    return WindowSource(name, split, store, rec)


@pytest.fixture(scope="module")
def sim10():
    return _sim(seed=1)


# ----------------------------------------------------------------------------- extraction


def test_count_shapes_spacing_bias_and_states(sim10, tmp_path):
    rec = _write_recovery(tmp_path / "rec", sim10)
    sw = extract_windows(sim10.sequence, rec, "train", WindowConfig())
    a = sw.arrays
    # 10 s at 200 Hz = 2001 samples; 1-s windows (200 intervals, 201 samples) every 100 samples: 19
    assert len(sw) == 19 and sw.candidates == 19
    assert sw.split is Split.TRAIN
    assert a["imu"].shape == (19, 201, 6) and a["bias"].shape == (19, 201, 6) and a["bias_std"].shape == (19, 201, 6)
    assert a["t_ns"].shape == (19, 201) and a["t_ns"].dtype == np.int64
    assert a["start_R"].shape == (19, 3, 3) and a["end_p"].shape == (19, 3)
    assert sum(sw.dropped.values()) == 0
    t = sim10.sequence.imu.t_ns
    np.testing.assert_array_equal(np.diff(a["t_ns"][:, 0]), np.full(18, NS // 2))  # t0 every 0.5 s
    assert a["t_ns"][0, 0] == t[0] and a["t_ns"][-1, -1] == t[-1]
    assert np.all(a["t_ns"][:, -1] - a["t_ns"][:, 0] == NS)
    idx = 100 * np.arange(19)[:, None] + np.arange(201)[None, :]
    np.testing.assert_array_equal(a["imu"], sim10.sequence.imu.imu_6[idx])
    np.testing.assert_array_equal(a[TEMPERATURE], sim10.sequence.imu.temperature_degc[idx])
    # the bias and its sigma are the interpolation stage's numbers at the IMU stamps
    expect = interpolate_bias(read_bias_csv(rec / "bias.csv"), t, random_walk=read_report(rec).require_random_walk())
    np.testing.assert_array_equal(a["bias"], expect.bias[idx])
    np.testing.assert_array_equal(a["bias_std"], expect.std[idx])
    assert np.all(a["bias_std"] > 0)
    # start and end states are the simulator's truth at the first and last stamp
    gt = sim10.sequence.ground_truth
    np.testing.assert_array_equal(gt.t_ns, t)
    s, e = idx[:, 0], idx[:, -1]
    np.testing.assert_allclose(a["start_p"], gt.p_m[s], atol=1e-12)
    np.testing.assert_allclose(a["end_p"], gt.p_m[e], atol=1e-12)
    np.testing.assert_allclose(a["start_v"], gt.v_mps[s], atol=1e-12)
    np.testing.assert_allclose(a["end_v"], gt.v_mps[e], atol=1e-12)
    R = Rotation.from_quat(gt.quat_wxyz, scalar_first=True).as_matrix()
    np.testing.assert_allclose(a["start_R"], R[s], atol=1e-9)
    np.testing.assert_allclose(a["end_R"], R[e], atol=1e-9)
    assert sw.info["reference"] == "state" and sw.info["rate_hz"] == pytest.approx(200.0)


def test_window_length_and_overlap_are_configurable(sim10, tmp_path):
    rec = _write_recovery(tmp_path / "rec", sim10)
    sw = extract_windows(sim10.sequence, rec, "test", WindowConfig(window_s=2.0, overlap=0.0))
    assert len(sw) == 5 and sw.arrays["imu"].shape == (5, 401, 6)
    np.testing.assert_array_equal(np.diff(sw.arrays["t_ns"][:, 0]), np.full(4, 2 * NS))


def test_windows_crossing_an_imu_gap_are_dropped(sim10, tmp_path):
    rec = _write_recovery(tmp_path / "rec", sim10)
    imu = sim10.sequence.imu
    keep = np.ones(len(imu), bool)
    keep[804:840] = False  # 180 ms gap between samples 803 and 840 (new indices 803 -> 804)
    seq = dataclasses.replace(sim10.sequence, imu=imu.take(keep))
    sw = extract_windows(seq, rec, "train", WindowConfig())
    # 1965 samples -> starts 0, 100, ..., 1700 (18); those at 700 and 800 span the gap interval
    assert sw.candidates == 18 and len(sw) == 16
    assert sw.dropped["imu_gap"] == 2
    assert not np.any((sw.arrays["t_ns"][:, 0] < imu.t_ns[840]) & (sw.arrays["t_ns"][:, -1] > imu.t_ns[803]))
    assert np.all(np.diff(sw.arrays["t_ns"], axis=1) <= 2 * NS // 200)


def test_windows_outside_the_recovered_span_are_dropped(sim10, tmp_path):
    rec = _write_recovery(tmp_path / "rec", sim10, span_s=(2.0, 7.0))
    sw = extract_windows(sim10.sequence, rec, "train", WindowConfig())
    # windows [s, s + 200] inside samples [400, 1400]: s = 400, 500, ..., 1200
    assert len(sw) == 9 and sw.dropped["outside_recovery"] == 10
    t = sim10.sequence.imu.t_ns
    np.testing.assert_array_equal(sw.arrays["t_ns"][:, 0], t[400:1201:100])


def test_pose_reference_when_the_sequence_has_no_ground_truth(tmp_path):
    """No ground-truth state: start/end states come from the poses with the recovery's offset and extrinsic."""
    sim = simulate(SimConfig(duration_s=10.0, seed=5, poses=PoseStreamConfig(
        clock_offset_s=0.0123, extrinsic_rotation_deg=5.0, extrinsic_translation_m=0.08)).noise_free())
    rec = _write_recovery(tmp_path / "rec", sim, offset_s=sim.truth.clock_offset_s,
                          T_imu_pose=sim.truth.T_imu_frame)
    seq = dataclasses.replace(sim.sequence, ground_truth=None)
    sw = extract_windows(seq, rec, "train", WindowConfig())
    assert sw.info["reference"] == "poses"
    assert sw.info["reference_info"]["time_offset_s"] == pytest.approx(0.0123)
    assert len(sw) >= 17  # the poses start a little after the IMU (random phase, clock offset)
    gt = sim.sequence.ground_truth
    i = np.searchsorted(gt.t_ns, sw.arrays["t_ns"][:, 0])
    np.testing.assert_array_equal(gt.t_ns[i], sw.arrays["t_ns"][:, 0])
    assert np.max(np.abs(sw.arrays["start_p"] - gt.p_m[i])) < 2e-3
    assert np.max(np.abs(sw.arrays["start_v"] - gt.v_mps[i])) < 0.03
    R = Rotation.from_quat(gt.quat_wxyz[i], scalar_first=True).as_matrix()
    ang = Rotation.from_matrix(np.swapaxes(sw.arrays["start_R"], 1, 2) @ R).magnitude()
    assert np.degrees(ang.max()) < 0.05


# ----------------------------------------------------------------------------- rates


def test_another_rate_is_refused_unless_resampled(sim10, tmp_path):
    slow = _sim(seed=2, rate_hz=100.0)
    a = _source(tmp_path, sim10, "fast", "train")
    b = _source(tmp_path, slow, "slow", "test")
    with pytest.raises(DataError) as exc:
        build_window_dataset([a, b], tmp_path / "ds", WindowConfig())
    msg = str(exc.value)
    assert "'slow'" in msg and "100.000 Hz" in msg and "--resample-hz" in msg and "\n" not in msg
    assert not (tmp_path / "ds").exists()

    m = build_window_dataset([a, b], tmp_path / "ds", WindowConfig(resample_hz=200.0))
    assert m["window_samples"] == 201 and m["rate_hz"] == 200.0
    assert m["sequences"]["slow"]["windows"] == 19
    assert m["sequences"]["slow"]["info"]["resampled"] is True
    assert m["sequences"]["slow"]["info"]["recorded_rate_hz"] == pytest.approx(100.0)
    assert m["sequences"]["fast"]["info"]["resampled"] is False  # already at 200 Hz: kept as recorded
    imu = np.load(tmp_path / "ds" / "sequences" / "slow" / "imu.npy")
    rec = slow.sequence.imu.imu_6
    np.testing.assert_allclose(imu[0, 0::2], rec[:101], rtol=0, atol=1e-12)  # recorded samples kept
    np.testing.assert_allclose(imu[0, 1::2], 0.5 * (rec[:100] + rec[1:101]), atol=1e-12)  # linear in between


def test_non_uniform_stamps_are_refused_unless_resampled(sim10, tmp_path):
    imu = sim10.sequence.imu
    rng = np.random.default_rng(0)
    t = imu.t_ns.copy()
    jitter = rng.choice(np.arange(1, len(t) - 1), 100, replace=False)
    t[jitter] += 1_500_000  # 1.5 ms on 5 % of the stamps
    seq = dataclasses.replace(sim10.sequence, imu=ImuSeries(t, imu.gyro_radps, imu.acc_mps2))
    rec = _write_recovery(tmp_path / "rec", sim10)
    with pytest.raises(DataError, match="non-uniform IMU stamps.*--resample-hz"):
        extract_windows(seq, rec, "train", WindowConfig())
    sw = extract_windows(seq, rec, "train", WindowConfig(resample_hz=200.0))
    assert len(sw) == 19 and sw.info["resampled"]
    np.testing.assert_array_equal(sw.arrays["t_ns"][:, 0], imu.t_ns[0:1801:100])


def test_resampling_keeps_gaps():
    t = np.concatenate([np.arange(0, 100), np.arange(150, 250)]).astype(np.int64) * 10_000_000  # 100 Hz, 0.5-s gap
    x = (t / NS)[:, None] * np.ones((1, 3))
    out = resample_imu(ImuSeries(t, x, 2 * x), 200.0)
    assert out.t_ns[0] == 0 and out.t_ns[-1] == t[-1]
    assert np.max(np.diff(out.t_ns)) == 510_000_000  # 0.99 s -> 1.50 s: no reading invented inside the gap
    assert len(out) == 199 + 199
    np.testing.assert_allclose(out.gyro_radps[:, 0], out.t_ns / NS, atol=1e-12)


# ----------------------------------------------------------------------------- config and splits


def test_window_config_dict_round_trip_and_errors():
    cfg = WindowConfig.from_dict({"window_s": 2, "resample_hz": 100})
    assert cfg == WindowConfig(window_s=2.0, overlap=0.5, resample_hz=100.0, gap_factor=2.0)
    assert WindowConfig.from_dict(cfg.to_dict()) == cfg
    assert WindowConfig.from_dict(None) == WindowConfig()
    with pytest.raises(ConfigError, match="unknown key 'window_len'"):
        WindowConfig.from_dict({"window_len": 1.0})
    for bad in ({"overlap": 1.0}, {"window_s": 0}, {"resample_hz": -5}, {"gap_factor": 1.0}):
        with pytest.raises(ConfigError):
            WindowConfig.from_dict(bad)


def test_a_sequence_in_two_splits_is_a_config_error(sim10, tmp_path):
    a = _source(tmp_path, sim10, "A", "train")
    twin = WindowSource("A", "test", a.store_dir, a.recovery_dir)
    with pytest.raises(ConfigError, match="'A' is listed in splits train and test"):
        build_window_dataset([a, twin], tmp_path / "ds", WindowConfig())
    with pytest.raises(ConfigError, match="no sequence in split 'train'"):
        build_window_dataset([twin], tmp_path / "ds", WindowConfig())
    assert not (tmp_path / "ds").exists()
    f = tmp_path / "splits.yaml"
    f.write_text("train: [MH_01, MH_03]\ntest: [MH_02, MH_01]\n")
    with pytest.raises(ConfigError, match="'MH_01' is listed in splits train and test"):
        read_splits_file(f)
    f.write_text("train: [MH_01]\nvalidation: [MH_02]\n")
    with pytest.raises(ConfigError, match="unknown split 'validation'"):
        read_splits_file(f)


def test_airimu_euroc_split_file(tmp_path):
    f = tmp_path / "euroc.yaml"
    f.write_text("train: [MH_01, MH_03, MH_05, V1_02, V2_01, V2_03]\ntest: [MH_02, MH_04, V1_03, V2_02]\n")
    splits = read_splits_file(f)
    assert splits == {Split.TRAIN: ["MH_01", "MH_03", "MH_05", "V1_02", "V2_01", "V2_03"],
                      Split.TEST: ["MH_02", "MH_04", "V1_03", "V2_02"]}
    with pytest.raises(InputFormatError, match="no ingest output for sequence 'MH_01'"):
        sources_from_results(splits, tmp_path / "results")


def test_normalisation_comes_from_the_train_split_only(sim10, tmp_path):
    train = [_source(tmp_path, sim10, "A", "train"), _source(tmp_path, _sim(seed=3), "B", "train")]
    m1 = build_window_dataset(train + [_source(tmp_path, _sim(seed=4), "C", "test")], tmp_path / "ds1")
    stacked = {k: np.concatenate([np.load(tmp_path / "ds1" / "sequences" / n / f"{k}.npy") for n in ("A", "B")])
               for k in ("imu", "bias")}
    for k in ("imu", "bias"):
        flat = stacked[k].reshape(-1, 6)
        np.testing.assert_allclose(m1["normalization"][f"{k}_mean"], flat.mean(axis=0), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(m1["normalization"][f"{k}_std"], flat.std(axis=0, ddof=1), rtol=1e-10)
    temps = np.concatenate([np.load(tmp_path / "ds1" / "sequences" / n / f"{TEMPERATURE}.npy") for n in ("A", "B")])
    np.testing.assert_allclose(m1["normalization"]["temperature_mean"], [temps.mean()], rtol=1e-12)
    np.testing.assert_allclose(m1["normalization"]["temperature_std"], [temps.std(ddof=1)], rtol=1e-10)
    other = _sim(seed=9)
    m2 = build_window_dataset(train + [_source(tmp_path, other, "D", "test")], tmp_path / "ds2")
    assert m2["normalization"] == m1["normalization"]
    d = np.load(tmp_path / "ds2" / "sequences" / "D" / "imu.npy")
    c = np.load(tmp_path / "ds1" / "sequences" / "C" / "imu.npy")
    assert not np.allclose(c, d)  # the test data did change


# ----------------------------------------------------------------------------- dataset on disk


@pytest.fixture(scope="module")
def dataset(sim10, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ds")
    sources = [_source(tmp, sim10, "A", "train"), _source(tmp, _sim(seed=6), "B", "test", span_s=(2.0, 7.0))]
    manifest = build_window_dataset(sources, tmp / "ds", WindowConfig())
    return tmp / "ds", manifest, sources


def test_manifest_content(dataset, tmp_path):
    root, m, sources = dataset
    assert read_manifest(root).data == m.data
    assert m["code_version"] == __version__ and m["format_version"] == 1
    assert m["config"] == {"window_s": 1.0, "overlap": 0.5, "resample_hz": None, "gap_factor": 2.0, "accept_warn": False}
    assert len(m["config_hash"]) == 16
    assert m["splits"] == {"train": ["A"], "test": ["B"]}
    assert m["sequences"]["A"]["windows"] == 19 and m["sequences"]["A"]["candidates"] == 19
    assert m["sequences"]["B"]["windows"] == 9 and m["sequences"]["B"]["dropped"]["outside_recovery"] == 10
    assert m["totals"]["test"] == {"sequences": 1, "windows": 9, "candidates": 19, "dropped": 10}
    assert m["window_samples"] == 201 and m["rate_hz"] == 200.0
    assert set(m["normalization"]) == {"imu_mean", "imu_std", "bias_mean", "bias_std", "temperature_mean",
                                       "temperature_std"}
    assert m["has_temperature"] is True  # the simulator reports the IMU temperature
    assert sorted(p.name for p in (root / "sequences" / "A").iterdir()) == sorted(
        f"{k}.npy" for k in (*ARRAYS, TEMPERATURE, STATE_BIAS))  # the simulator writes a ground-truth state
    cal = read_store(sources[0].store_dir).calibration
    assert m["sequences"]["A"]["info"]["sensor_random_walk"] == [cal.gyro_random_walk] * 3 + [cal.acc_random_walk] * 3
    m2 = build_window_dataset(sources[:1], tmp_path / "ds2", WindowConfig(window_s=2.0))
    assert m2["config_hash"] != m["config_hash"]
    m3 = build_window_dataset(sources[:1], tmp_path / "ds3", WindowConfig())
    assert m3["config_hash"] == m["config_hash"]
    summary = format_summary(m).splitlines()
    assert summary[1].split() == ["train", "1", "19", "0", "-"]
    assert summary[2].split() == ["test", "1", "9", "10", "outside_recovery", "10"]


def test_window_dataset_is_memory_mapped_and_loads_through_a_dataloader(dataset, sim10):
    root, m, _ = dataset
    ds = WindowDataset(root, "train")
    assert isinstance(ds, torch.utils.data.Dataset)
    assert ds.sequences == ["A"] and len(ds) == 19
    assert all(isinstance(v, np.memmap) for v in ds.arrays("A").values())
    item = ds[3]
    assert item["imu"].shape == (201, 6) and item["imu"].dtype == torch.float32
    assert item["dt_s"].shape == (200,) and torch.allclose(item["dt_s"], torch.full((200,), 0.005))
    assert item["t0_ns"] == int(sim10.sequence.imu.t_ns[300]) and item["sequence"] == "A"
    np.testing.assert_allclose(item["bias"].numpy(), np.load(root / "sequences/A/bias.npy")[3], rtol=1e-6)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, shuffle=False, num_workers=0)
    batches = list(loader)
    assert [len(b["sequence"]) for b in batches] == [4, 4, 4, 4, 3]
    b = batches[0]
    shapes = {k: tuple(v.shape) for k, v in b.items() if k != "sequence"}
    assert shapes == {"imu": (4, 201, 6), "bias": (4, 201, 6), "bias_std": (4, 201, 6), "dt_s": (4, 200),
                      "start_R": (4, 3, 3), "start_v": (4, 3), "start_p": (4, 3), "end_R": (4, 3, 3),
                      "end_v": (4, 3), "end_p": (4, 3), "t0_ns": (4,), TEMPERATURE: (4, 201)}
    assert ds.has_temperature
    np.testing.assert_allclose(item[TEMPERATURE].numpy(), sim10.sequence.imu.temperature_degc[300:501], rtol=1e-6)
    assert b["t0_ns"].dtype == torch.int64 and b["sequence"] == ["A"] * 4
    assert torch.equal(b["t0_ns"], torch.as_tensor(sim10.sequence.imu.t_ns[[0, 100, 200, 300]]))
    clone = pickle.loads(blob := pickle.dumps(ds))  # what a 'spawn' DataLoader worker receives
    assert len(blob) < 50_000 and isinstance(clone.arrays("A")["imu"], np.memmap)
    assert torch.equal(clone[7]["imu"], ds[7]["imu"])
    test = WindowDataset(root, Split.TEST, dtype=torch.float64)
    assert len(test) == 9 and test[0]["end_p"].dtype == torch.float64
    assert len(WindowDataset(root, "val")) == 0


def test_temperature_only_when_every_sequence_carries_it(sim10, tmp_path):
    """One sequence without temperature: the dataset has none (no files, no stats, no item key)."""
    bare = dataclasses.replace(sim10, sequence=dataclasses.replace(
        sim10.sequence, imu=dataclasses.replace(sim10.sequence.imu, temperature_degc=None)))
    sources = [_source(tmp_path, sim10, "A", "train"), _source(tmp_path, bare, "B", "test")]
    m = build_window_dataset(sources, tmp_path / "ds")
    assert m["has_temperature"] is False and "temperature_mean" not in m["normalization"]
    assert not list((tmp_path / "ds").rglob(f"{TEMPERATURE}.npy"))
    ds = WindowDataset(tmp_path / "ds", "train")
    assert not ds.has_temperature and TEMPERATURE not in ds[0]


def test_temperature_from_simulation_to_window_items(tmp_path):
    """sim -> ASL folder -> reader -> store -> windows -> WindowDataset: the temperature arrives unchanged."""
    from pipeline.io.asl import read_asl
    from pipeline.sim import TemperatureConfig, write_simulation
    from pipeline.store import read_store

    warm = TemperatureConfig(warmup_delta_degc=10.0, warmup_tau_s=4.0, sensor_tau_s=1.0)
    sim = simulate(SimConfig(duration_s=10.0, seed=2, name="S", imu=ImuNoiseConfig(temperature=warm)))
    store = write_store(read_asl(write_simulation(sim, tmp_path / "asl"), name="S"), tmp_path / "store")
    temperature = read_store(store).imu.temperature_degc
    np.testing.assert_array_equal(temperature, sim.sequence.imu.temperature_degc)
    assert temperature[-1] - temperature[0] > 9.0
    rec = _write_recovery(tmp_path / "rec", sim)
    build_window_dataset([WindowSource("S", "train", store, rec)], tmp_path / "ds")
    ds = WindowDataset(tmp_path / "ds", "train", dtype=torch.float64)
    assert len(ds) == 19
    for i in (0, 7, 18):
        np.testing.assert_array_equal(ds[i][TEMPERATURE].numpy(), temperature[100 * i:100 * i + 201])


def test_a_failure_leaves_no_output(sim10, tmp_path):
    good = _source(tmp_path, sim10, "A", "train")
    broken = WindowSource("B", "test", good.store_dir, tmp_path / "missing_recovery")
    with pytest.raises(InputFormatError, match="recovery output lacks"):
        build_window_dataset([good, broken], tmp_path / "out" / "ds")
    assert not (tmp_path / "out" / "ds").exists()
    assert list((tmp_path / "out").iterdir()) == []  # no temporary folder left behind
    first = build_window_dataset([good], tmp_path / "out" / "ds")
    with pytest.raises(InputFormatError):
        build_window_dataset([good, broken], tmp_path / "out" / "ds", WindowConfig(window_s=2.0))
    assert read_manifest(tmp_path / "out" / "ds").data == first.data  # the previous dataset is untouched
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["ds"]


# ----------------------------------------------------------------------------- CLI


def test_cli_end_to_end_on_two_simulated_sequences(tmp_path, capsys):
    results = tmp_path / "results"
    for name, seed in (("sim_a", 11), ("sim_b", 12)):
        sim = _sim(seed=seed, name=name)
        write_store(sim.sequence, results / "ingest" / name)
        _write_recovery(results / "recovery" / name, sim, span_s=(0.0, 10.0) if name == "sim_a" else (0.0, 5.0))
    splits = tmp_path / "splits.yaml"
    splits.write_text("train: [sim_a]\ntest: [sim_b]\n")
    # no results/validation/NAME: refused unless said explicitly (it could be a recording validate FAILs)
    rc = main(["windows", "--splits", str(splits), "--results", str(results), "--out", str(tmp_path / "ds")])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1, err
    assert "2 sequence(s) not validated: 'sim_a', 'sim_b'" in err[0] and "--allow-unvalidated" in err[0]
    assert str(results / "validation" / "sim_a") in err[0]
    assert not (tmp_path / "ds").exists()
    rc = main(["windows", "--splits", str(splits), "--results", str(results), "--out", str(tmp_path / "ds"),
               "--allow-unvalidated"])
    out = capsys.readouterr().out.splitlines()
    assert rc == 0
    assert out[0].startswith("2 sequences, 201 samples per window (1 s at 200 Hz, overlap 0.5)")
    assert out[2].split() == ["train", "1", "19", "0", "-"]
    assert out[3].split() == ["test", "1", "9", "10", "outside_recovery", "10"]
    m = read_manifest(tmp_path / "ds")
    assert m["splits"] == {"train": ["sim_a"], "test": ["sim_b"]}
    assert len(WindowDataset(tmp_path / "ds", "test")) == 9
    # with the sequence records (training.data.records): each whole IMU record once, the test one too
    from pipeline.store import read_store
    from training.data.records import open_context

    imu = read_store(results / "ingest" / "sim_b").imu
    rec = open_context(tmp_path / "ds", "sim_b")
    np.testing.assert_array_equal(np.asarray(rec.imu), np.hstack([imu.gyro_radps, imu.acc_mps2]))
    np.testing.assert_array_equal(np.asarray(rec.t_ns), imu.t_ns)

    # --seq without --validation: refused the same way
    rc = main(["windows", "--seq", "sim_a", "train", str(results / "ingest/sim_a"), str(results / "recovery/sim_a"),
               "--out", str(tmp_path / "ds2")])
    err = capsys.readouterr().err
    assert rc == 2 and "1 sequence(s) not validated: 'sim_a' (no --validation NAME=DIR)" in err

    # the same through --seq, with another window length
    rc = main(["windows", "--seq", "sim_a", "train", str(results / "ingest/sim_a"), str(results / "recovery/sim_a"),
               "--seq", "sim_b", "val", str(results / "ingest/sim_b"), str(results / "recovery/sim_b"),
               "--window-s", "2", "--overlap", "0", "--out", str(tmp_path / "ds2"), "--allow-unvalidated"])
    assert rc == 0
    m2 = read_manifest(tmp_path / "ds2")
    assert m2["window_samples"] == 401 and m2["sequences"]["sim_a"]["windows"] == 5
    assert m2["splits"] == {"train": ["sim_a"], "val": ["sim_b"]}
    capsys.readouterr()

    # one name in two splits: one-line error, exit 2, nothing written
    rc = main(["windows", "--splits", str(splits), "--results", str(results), "--out", str(tmp_path / "ds3"),
               "--allow-unvalidated", "--seq", "sim_a", "test", str(results / "ingest/sim_a"), str(results / "recovery/sim_a")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "'sim_a' is listed in splits test and train" in err[0]
    assert not (tmp_path / "ds3").exists()
    rc = main(["windows", "--splits", str(splits), "--out", str(tmp_path / "ds3")])
    assert rc == 2 and "--splits and --results go together" in capsys.readouterr().err


def test_split_none_is_not_windowed(sim10, tmp_path):
    """'none' means "no role in training" everywhere: such a sequence gets no windows."""
    train = _source(tmp_path, sim10, "a", "train")
    unused = _source(tmp_path, sim10, "b", "none")
    manifest = build_window_dataset([train, unused], tmp_path / "ds")
    assert list(manifest.sequences) == ["a"] and manifest.names(Split.NONE) == []
    assert not (tmp_path / "ds" / "sequences" / "b").exists()


# ----------------------------------------------------------------------------- verdict gate


def _validated(tmp: Path, src: WindowSource, *, acc_offset_mps2: float = 0.0) -> WindowSource:
    """``src`` with a validation folder written by the validate stage for its recovery (shifted on acc x)."""
    from pipeline.store import read_store
    from validation.validate import validate_inputs, write_validation

    rec = src.recovery_dir
    if acc_offset_mps2:
        frame = pd.read_csv(rec / "bias.csv")
        frame["ba_x"] += acc_offset_mps2
        frame.to_csv(rec / "bias.csv", index=False, float_format="%.12g")
    result = validate_inputs(read_store(src.store_dir), recovery_dir=rec)
    out = write_validation(result, tmp / "val" / src.name)
    return dataclasses.replace(src, validation_dir=out)


def test_windows_take_only_sequences_whose_verdict_allows_it(sim10, tmp_path):
    good = _validated(tmp_path, _source(tmp_path, sim10, "good", "train"))
    bad = _validated(tmp_path, _source(tmp_path, _sim(seed=7), "bad", "train"), acc_offset_mps2=0.5)
    test = _source(tmp_path, _sim(seed=8), "unchecked", "test")
    m = build_window_dataset([good, bad, test], tmp_path / "ds", WindowConfig())
    assert set(m["sequences"]) == {"good", "unchecked"}
    assert m["excluded"]["bad"].startswith("validation FAIL: ")
    assert m["not_validated"] == ["unchecked"]
    assert "left out: bad: validation FAIL" in format_summary(m)
    with pytest.raises(ConfigError, match=r"none of the 1 train sequence\(s\) is usable") as info:
        build_window_dataset([bad, test], tmp_path / "ds2", WindowConfig())
    assert "accept_warn" not in str(info.value)  # FAIL is never taken: no option to suggest
    assert not (tmp_path / "ds2").exists()


def test_window_labels_carry_the_sigma_widened_by_the_heldout_check(sim10, tmp_path, caplog):
    """Where validation.json's held-out check widened an axis' sigma, the dataset's bias_std is the
    recovered sigma times that factor (the manifest says by how much); without a check it is the recovered one."""
    plain = _source(tmp_path, sim10, "A", "train")
    validated = _validated(tmp_path, plain)
    path = validated.validation_dir / "validation.json"
    data = json.loads(path.read_text())
    factor = [2.0, 1.0, 1.0, 1.0, 1.0, 3.5]
    data.setdefault("heldout", {})["sigma_check"] = {"blocks": 8, "chi2": [40.0, 5, 5, 5, 5, 98.0], "bound": 20.0,
                                                     "factor": factor}
    path.write_text(json.dumps(data))
    m0 = build_window_dataset([plain], tmp_path / "ds0", WindowConfig())
    with caplog.at_level("WARNING", logger="training.data.windows"):
        m1 = build_window_dataset([validated], tmp_path / "ds1", WindowConfig())
    assert "sequence 'A': its labels' bias sigma is widened by the validation's held-out check (x2.00, 1.00, 1.00, " \
           "1.00, 1.00, 3.50" in caplog.text
    std0, std1 = (np.load(root / "sequences" / "A" / "bias_std.npy") for root in (tmp_path / "ds0", tmp_path / "ds1"))
    assert np.all(std0 > 0)
    np.testing.assert_allclose(std1, std0 * np.array(factor), rtol=1e-12)
    np.testing.assert_array_equal(np.load(tmp_path / "ds1" / "sequences" / "A" / "bias.npy"),
                                  np.load(tmp_path / "ds0" / "sequences" / "A" / "bias.npy"))
    assert m1["sequences"]["A"]["info"]["bias_std_factor"] == factor
    assert m0["sequences"]["A"]["info"]["bias_std_factor"] == [1.0] * 6
    data["heldout"]["sigma_check"]["factor"] = [0.5] * 6  # a factor never narrows: a damaged file is refused
    path.write_text(json.dumps(data))
    with pytest.raises(InputFormatError, match="heldout.sigma_check.factor") as exc:
        build_window_dataset([validated], tmp_path / "ds2", WindowConfig())
    assert exc.value.path == str(path)
    assert not (tmp_path / "ds2").exists()


def test_windows_where_every_verdict_is_fail_is_one_short_line(sim10, tmp_path, capsys):
    """Every sequence FAILs: one line saying none of N is usable, the reasons, and where the reports are."""
    from biasgt.cli.app import main

    srcs = [_validated(tmp_path, _source(tmp_path, _sim(seed=7 + i), f"bad{i}", split), acc_offset_mps2=0.5 + 0.1 * i)
            for i, split in enumerate(["train", "val", "test", "train"])]
    args = ["windows", "--out", str(tmp_path / "ds")]
    for s in srcs:
        args += ["--seq", s.name, s.split.value, str(s.store_dir), str(s.recovery_dir),
                 "--validation", f"{s.name}={s.validation_dir}"]
    assert main(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    line = err[0]
    assert line.startswith(f"biasgt windows: error: {tmp_path / 'val'}: none of the 4 sequences is usable (left out "
                           "by their validation verdict): bad0: validation FAIL: "), line
    for s in srcs[:3]:  # the worst three, each with its whole first reason
        reason = json.loads((s.validation_dir / "validation.json").read_text())["reasons"][0]
        assert f"{s.name}: validation FAIL: {reason}" in line, line
    assert "; and 1 more (bad3); the reports say why (" + str(tmp_path / "val" / "<sequence>" / "validation.json") in line
    assert "accept_warn" not in line and len(line) < 1500, line
    assert not (tmp_path / "ds").exists()


def test_windows_take_the_validations_reference_stream(sim10, tmp_path):
    """A bias recovered from positions only (no orientation): the windows' states come from the stream
    the validation used (here ground-truth poses of the IMU), as MH_01's Leica recovery needs."""
    from pipeline.errors import ValidationError
    from pipeline.types import PoseSeries, PoseSourceKind

    seq = sim10.sequence
    gt = seq.ground_truth
    poses = {"leica0": PoseSeries(gt.t_ns[::10], gt.p_m[::10], None, "prism", PoseSourceKind.POSITION_TRACKER),
             "gt_poses": PoseSeries(gt.t_ns, gt.p_m, gt.quat_wxyz, "imu", PoseSourceKind.GROUND_TRUTH)}
    no_state = dataclasses.replace(seq, name="m", ground_truth=None, poses=poses)
    store = write_store(no_state, tmp_path / "stores" / "m")
    rec = _write_recovery(tmp_path / "rec" / "m", sim10)
    with pytest.raises(ValidationError, match="positions only"):
        extract_windows(no_state, rec, "train", WindowConfig(), reference_stream="leica0")
    sw = extract_windows(no_state, rec, "train", WindowConfig(), reference_stream="gt_poses")
    assert len(sw) > 10 and sw.info["reference"] == "poses"
    np.testing.assert_allclose(sw.arrays["start_p"], gt.p_m[np.searchsorted(gt.t_ns, sw.arrays["t_ns"][:, 0])],
                               atol=2e-3)
    m = build_window_dataset([WindowSource("m", "train", store, rec, reference_stream="gt_poses")],
                             tmp_path / "ds")
    assert m.sequences["m"].windows == len(sw)


def test_cli_reference_option_and_its_hint(sim10, tmp_path, capsys):
    from pipeline.types import PoseSeries, PoseSourceKind

    gt = sim10.sequence.ground_truth
    poses = {"leica0": PoseSeries(gt.t_ns[::10], gt.p_m[::10], None, "prism", PoseSourceKind.POSITION_TRACKER),
             "gt_poses": PoseSeries(gt.t_ns, gt.p_m, gt.quat_wxyz, "imu", PoseSourceKind.GROUND_TRUTH)}
    store = write_store(dataclasses.replace(sim10.sequence, name="m", ground_truth=None, poses=poses),
                        tmp_path / "stores" / "m")
    rec = write_recovery_folder(tmp_path / "rec" / "m", BiasTrack(gt.t_ns[::10], np.zeros((len(gt.t_ns[::10]), 6)),
                                np.full((len(gt.t_ns[::10]), 6), 1e-3)),
                                {"noise": {"gyro_random_walk": RW[0], "acc_random_walk": RW[1]},
                                 "pose_stream": "leica0", "T_imu_pose": {"p_m": [0, 0, 0], "quat_wxyz": [1, 0, 0, 0]}})
    args = ["windows", "--seq", "m", "train", str(store), str(rec), "--out", str(tmp_path / "ds"), "--allow-unvalidated"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "has positions only" in err and "--reference m=gt_poses" in err
    assert main([*args, "--reference", "m=gt_poses"]) == 0
    assert read_manifest(tmp_path / "ds").sequences["m"].windows > 10


def test_the_validation_of_another_sequence_is_refused(sim10, tmp_path, capsys):
    """``--validation bad=<good's validation>``: refused naming what it judged, not taken as bad's verdict;
    a validation of the right store but another recovery is refused too."""
    good = _validated(tmp_path, _source(tmp_path, sim10, "good", "train"))
    bad = _validated(tmp_path, _source(tmp_path, _sim(seed=7), "bad", "train"), acc_offset_mps2=0.5)
    assert main(["windows", "--seq", "bad", "train", str(bad.store_dir), str(bad.recovery_dir),
                 "--validation", f"bad={good.validation_dir}", "--out", str(tmp_path / "ds")]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert err[0].startswith(f"biasgt windows: error: {good.validation_dir / 'validation.json'}: this validation "
                             f"judged sequence 'good', but sequence 'bad' is cut from store {bad.store_dir}, "
                             "which holds 'bad'"), err
    assert not (tmp_path / "ds").exists()
    # same name, another recovery (bad's store re-recovered after its validation)
    other = _write_recovery(tmp_path / "rec2" / "bad", _sim(seed=7), every=5)
    with pytest.raises(ConfigError, match="this validation judged another recovery than the one sequence 'bad'"):
        build_window_dataset([dataclasses.replace(bad, recovery_dir=other)], tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_a_recovery_of_another_sequence_is_refused(sim10, tmp_path, capsys):
    """``--seq a train STORE_a RECOVERY_b``: the recovery names sequence 'b' (recovery.json), the store holds 'a':
    refused before any window is cut, instead of windows of a's IMU labelled with b's bias."""
    src = _source(tmp_path, sim10, "a", "train")
    report = src.recovery_dir / "recovery.json"
    report.write_text(json.dumps({**json.loads(report.read_text()), "sequence": "b"}))
    assert main(["windows", "--seq", "a", "train", str(src.store_dir), str(src.recovery_dir), "--allow-unvalidated",
                 "--out", str(tmp_path / "ds")]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith(
        f"biasgt windows: error: {report}: this recovery is of sequence 'b', but sequence 'a' is cut from store "
        f"{src.store_dir}, which holds 'a'"), err
    assert not (tmp_path / "ds").exists()
