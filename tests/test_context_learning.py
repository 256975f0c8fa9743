"""Learning beyond a constant: sequence records, the start_rest / sequence_mean rows, the context model.

Values are checked against the simulation's own truth or closed forms computed here with numpy.
The learnability check trains in seconds at a tiny size.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.types import DEFAULT_GRAVITY_MPS2
from training.config import EvaluationConfig
from training.data.records import CONTEXT_DIR, SequenceContext, detect_rests, open_context
from training.context.model import ContextModelConfig, Stats, context_features, integration_errors
from training.data.dataset import WindowDataset
from training.evaluation.evaluate import evaluate_reference
from training.rows.sequence_mean import sequence_mean_bias
from training.rows.start_rest import start_rest_bias
from training.data.sim_context import RestSim, simulate_rest_sequence, write_rest_sim_dataset
from toy_windows import one_torch_thread  # noqa: F401 (a fixture)

SIM = RestSim(duration_s=20.0, rate_hz=50.0)
EVAL = EvaluationConfig(samples=1, gravity="recovered")


@pytest.fixture(scope="module")
def sim_dataset(tmp_path_factory):
    return write_rest_sim_dataset(tmp_path_factory.mktemp("restsim") / "ds", SIM, train=8, val=2, test=3, seed=1)


def test_detect_rests_finds_the_simulated_rest():
    seq = simulate_rest_sequence(SIM, 3)
    rests = detect_rests(seq["imu"], SIM.rate_hz)
    assert len(rests) >= 1
    first, stop = rests[0]
    assert first == 0
    # the rest lasts rest_s; the detector drops its last block as a margin
    assert SIM.rest_s - 0.5 <= stop / SIM.rate_hz <= SIM.rest_s


def test_start_rest_bias_matches_the_truth(sim_dataset):
    ctx = open_context(sim_dataset, "rest_test_00")
    seq = simulate_rest_sequence(SIM, 1 * 10_007 + 10)  # the generator's seed of rest_test_00
    np.testing.assert_array_equal(np.asarray(ctx.imu), seq["imu"])
    mean_train = np.zeros(6)
    est, found = start_rest_bias(ctx, np.array([len(seq["imu"])]), mean_train, 9.81)
    assert found[0]
    a, b = ctx.rests[0]
    true = seq["bias"][a:b].mean(0)
    np.testing.assert_allclose(est[0, :3], true[:3], atol=3 * SIM.gyro_noise / np.sqrt(b - a) + 1e-5)
    acc = seq["imu"][a:b, 3:].mean(0)
    u = acc / np.linalg.norm(acc)
    assert est[0, 3:] @ u == pytest.approx(true[3:] @ u, abs=0.01)  # along gravity: observable
    assert np.linalg.norm(est[0, 3:] - (est[0, 3:] @ u) * u) < 1e-12  # across it: the train mean (0 here)


def test_start_rest_is_causal_and_falls_back_to_the_train_mean(sim_dataset):
    ctx = open_context(sim_dataset, "rest_test_00")
    mean_train = np.arange(6.0)
    est, found = start_rest_bias(ctx, np.array([5]), mean_train, 9.81)  # a window ending at sample 5
    assert not found[0]
    np.testing.assert_array_equal(est[0], mean_train)
    T = int(SIM.rate_hz) + 1
    t0 = np.asarray(ctx.t_ns[[0, 200, 400]])
    stats = Stats.from_manifest(dict(WindowDataset(sim_dataset).manifest.normalization))
    cfg = ContextModelConfig(use_temperature=True)
    before, _ = context_features(ctx, t0, T, stats, cfg, 9.81)
    altered = SequenceContext(ctx.name, np.array(ctx.imu), ctx.t_ns, np.array(ctx.temperature_degc), ctx.rate_hz,
                              list(ctx.rests))
    altered.imu[400 + T:] += 5.0  # the future of the last window
    after, _ = context_features(altered, t0, T, stats, cfg, 9.81)
    np.testing.assert_array_equal(before, after)


def test_write_context_from_stores_matches_the_windows(tmp_path):
    from window_data import make_window_dataset

    from training.data.records import write_context

    ds = make_window_dataset(tmp_path, splits={"train": 1, "val": 1, "test": 1}, duration_s=6.0)
    write_context(ds)
    data = WindowDataset(ds, "test", dtype=torch.float64)
    name = data.sequences[0]
    a = data.arrays(name)
    ctx = SequenceContext.open(ds, name)
    i = ctx.index(np.asarray(a["t_ns"])[:, 0])
    T = a["imu"].shape[1]
    for w, start in enumerate(i):  # every window is its slice of the record, stamps and readings
        np.testing.assert_array_equal(ctx.t_ns[start:start + T], a["t_ns"][w])
        np.testing.assert_array_equal(np.asarray(ctx.imu[start:start + T]), a["imu"][w])


def test_sequence_mean_is_the_mean_label(sim_dataset):
    folder = sim_dataset / "sequences" / "rest_test_01"
    bias = np.load(folder / "bias.npy")
    np.testing.assert_allclose(sequence_mean_bias(folder), bias.reshape(-1, 6).mean(0), rtol=1e-12)


def test_context_costs_one_record_per_sequence(sim_dataset):
    folder = sim_dataset / CONTEXT_DIR / "rest_train_00"
    n = int(round(SIM.duration_s * SIM.rate_hz)) + 1
    payload = sum(np.load(folder / f).nbytes for f in ("imu.npy", "t_ns.npy", "temperature_degc.npy"))
    assert payload == n * 64  # 6 float64 + int64 stamp + float64 temperature per sample


def test_true_bias_integrates_to_the_reference(sim_dataset):
    ds = WindowDataset(sim_dataset, "test", dtype=torch.float64)
    a = ds.arrays("rest_test_00")
    t = lambda k: torch.from_numpy(np.array(a[k], dtype=np.float64))  # noqa: E731
    dt = torch.from_numpy(np.diff(np.asarray(a["t_ns"]), axis=1) * 1e-9)
    g = torch.tensor(DEFAULT_GRAVITY_MPS2, dtype=torch.float64)
    args = (dt, t("start_R"), t("start_v"), t("start_p"), t("end_R"), t("end_p"), g)
    imu = t("imu")
    rot_true, pos_true = integration_errors(imu, t("bias"), *args)
    rot_zero, pos_zero = integration_errors(imu, torch.zeros(len(imu), 6), *args)
    assert float(pos_true.sqrt().max()) < 0.01 < float(pos_zero.sqrt().mean())
    assert float(rot_true.sqrt().max()) < float(rot_zero.sqrt().mean()) / 5


def _closures(ds, result) -> dict[str, tuple[float, float]]:
    """The gap closed by every row (aggregation) of ``result``: '' (metric over samples), 'mean', 'median'."""
    refs = {b: evaluate_reference(b, ds, None, EVAL).summary.rows[0].average for b in ("train_mean", "ground_truth")}
    tm, gt = refs["train_mean"], refs["ground_truth"]
    return {r.key: ((tm.prmse_m - r.average.prmse_m) / (tm.prmse_m - gt.prmse_m),
                    (tm.roe_deg - r.average.roe_deg) / (tm.roe_deg - gt.roe_deg)) for r in result.summary.rows}


def _closure(ds, result) -> tuple[float, float]:
    """The gap from train_mean to the truth that ``result``'s first row closes (PRMSE, ROE)."""
    return _closures(ds, result)[result.summary.rows[0].key]


@pytest.mark.usefixtures("one_torch_thread")
def test_context_model_learns_the_bias_and_needs_its_input(sim_dataset):
    from training.context.train import ContextTrainConfig, evaluate_context, train_context

    def run(**model):
        cfg = ContextTrainConfig(model=ContextModelConfig(history_s=(), **model), steps=300, lr=3e-3, val_every=50,
                                 gravity="recovered")
        return _closure(sim_dataset, evaluate_context(train_context(sim_dataset, cfg), sim_dataset, EVAL))

    learned = run(base="rest", use_temperature=True)
    blind = run(base="mean", use_temperature=False, use_context=False)  # a model ignoring its input
    rest_only = _closure(sim_dataset, evaluate_reference("start_rest", sim_dataset, None, EVAL))
    assert min(learned) >= 0.8, learned
    assert learned[0] > rest_only[0] + 0.1, (learned, rest_only)  # the temperature term is learned
    assert max(blind) < 0.5, blind


@pytest.mark.usefixtures("one_torch_thread")
def test_context_diffusion_learns_the_bias_and_needs_its_input(sim_dataset):
    """The residual drawn by DDIM: its sample mean closes the simulated gap; samples drawn without the
    input spread over the train split's residuals and close none of it."""
    from training.context.diffusion import ContextDiffusion
    from training.context.train import ContextTrainConfig, evaluate_context, train_context

    sampled = EvaluationConfig(samples=8, samplers=["ddim"], gravity="recovered")

    def run(**model):
        cfg = ContextTrainConfig(model=ContextModelConfig(history_s=(), diffusion=True, **model), steps=600, lr=3e-3,
                                 val_every=50, gravity="recovered")
        trained = train_context(sim_dataset, cfg)
        assert isinstance(trained, ContextDiffusion)
        return _closures(sim_dataset, evaluate_context(trained, sim_dataset, sampled))

    learned = run(base="rest", use_temperature=True)
    blind = run(base="mean", use_temperature=False, use_context=False)
    assert min(learned["mean"]) >= 0.8 and min(learned[""]) >= 0.7, learned
    assert max(blind["mean"]) < 0.5 and max(blind[""]) < 0.5, blind


def test_context_diffusion_losses_follow_the_forward_process():
    """Against the closed forms: ``x0_hat`` is the target exactly when the noise estimate is exact, and
    the integration weights are ``min(alpha_bar / (1 - alpha_bar), 1)`` of the drawn steps."""
    from training.context.diffusion import ContextDiffusion

    model = ContextDiffusion(ContextModelConfig(history_s=(), diffusion=True), Stats(*(np.ones(6),) * 4))
    torch.nn.init.zeros_(model.denoiser[-1].weight)
    torch.nn.init.zeros_(model.denoiser[-1].bias)  # eps_hat = 0
    cond = torch.zeros(5, model.denoiser[0].in_features - 6 - 32)
    target = torch.randn(5, 6, generator=torch.Generator().manual_seed(3))
    gen = torch.Generator().manual_seed(7)
    mse, x0, w = model.losses(cond, target, gen)
    replay = torch.Generator().manual_seed(7)
    t = torch.randint(0, 1000, (5,), generator=replay)
    noise = torch.randn(5, 6, generator=replay)
    ab = torch.cumprod(1 - torch.linspace(1e-4, 0.02, 1000), 0)[t][:, None]
    x_t = ab.sqrt() * target + (1 - ab).sqrt() * noise
    torch.testing.assert_close(mse, noise.square().mean())
    torch.testing.assert_close(x0, x_t / ab.sqrt())
    torch.testing.assert_close(w, (ab / (1 - ab)).clamp(max=1)[:, 0])


def test_context_diffusion_refuses_an_integration_loss_alone():
    from pipeline.errors import ConfigError
    from training.context.train import ContextTrainConfig

    with pytest.raises(ConfigError, match="noise loss"):
        ContextTrainConfig(model=ContextModelConfig(diffusion=True), loss="integration")


@pytest.mark.usefixtures("one_torch_thread")
def test_registered_context_network_trains_and_evaluates_through_the_public_functions(sim_dataset, tmp_path):
    """``biasgt train --method context_residual`` / ``biasgt evaluate``'s functions: the batches carry the
    records' context, the checkpoint alone rebuilds the model, and it closes the simulated gap."""
    from training.fit.checkpoint import load_run
    from training.config import TrainConfig
    from training.evaluation.evaluate import evaluate_run
    from training.fit.train import train

    config = TrainConfig(method="context_residual", preset="tiny", seed=0, max_steps=300, batch_size=64, lr=3e-3,
                         warmup_steps=10, val_every=50, checkpoint_every=300, use_temperature=True, device="cpu",
                         model_overrides={"base": "rest", "history_s": (), "pos_scale_m": 0.01})
    runs = [train(config, sim_dataset, tmp_path / f"run{i}") for i in range(2)]
    results = [evaluate_run(r, sim_dataset, None, EVAL, method="context_residual") for r in runs]
    a, b = (r.summary.rows[0].average for r in results)
    assert (a.prmse_m, a.roe_deg) == (b.prmse_m, b.roe_deg)  # deterministic
    run = load_run(runs[0])
    assert run.model.config.network.base == "rest" and run.model.config.condition_channels == 7
    assert results[0].summary.method == "context_residual"
    closed = _closure(sim_dataset, results[0])
    assert min(closed) >= 0.8, closed


def test_the_record_rows_carry_table_i_footnotes_when_present():
    from types import SimpleNamespace

    from training.references import get_reference

    rest, mean = get_reference("start_rest"), get_reference("sequence_mean")
    assert not rest.oracle and mean.oracle  # start_rest is ranked; sequence_mean is a bound
    present = [SimpleNamespace(method="start_rest"), SimpleNamespace(method="sequence_mean")]
    assert "56 bytes per IMU sample" in rest.footnote(present)  # the records' memory cost
    assert mean.footnote(present).startswith("Sequence-mean bias (oracle")
    assert rest.footnote(present[1:]) is None and mean.footnote(present[:1]) is None
