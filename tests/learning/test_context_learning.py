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
from training.context.model import ContextModelConfig, Stats, context_features
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
    from training.models.bias_model import integration_errors

    g = torch.tensor(DEFAULT_GRAVITY_MPS2, dtype=torch.float64)
    args = (dt, t("start_R"), t("start_v"), t("start_p"), t("end_R"), t("end_v"), t("end_p"), g)
    imu = t("imu")
    rot_true, _, pos_true = integration_errors(imu, t("bias"), *args)
    rot_zero, _, pos_zero = integration_errors(imu, torch.zeros(len(imu), 6), *args)
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


def _trained(ds, out, method: str, steps: int, evaluation: EvaluationConfig, *, use_temperature: bool, lr: float = 1e-3,
             **options):
    """``method`` trained by the one trainer (``biasgt train``'s) and evaluated by ``biasgt evaluate``'s function."""
    from training.config import TrainConfig
    from training.evaluation.evaluate import evaluate_run
    from training.fit.train import train

    config = TrainConfig(method=method, preset="tiny", seed=0, max_steps=steps, batch_size=64, lr=lr,
                         warmup_steps=10, val_every=50, checkpoint_every=steps, use_temperature=use_temperature,
                         device="cpu", model_overrides={"history_s": (), **options})
    return evaluate_run(train(config, ds, out), ds, None, evaluation, method=method)


@pytest.mark.usefixtures("one_torch_thread")
def test_context_model_learns_the_bias_and_needs_its_input(sim_dataset, tmp_path):
    def run(name, **options):
        return _closure(sim_dataset, _trained(sim_dataset, tmp_path / name, "context_residual", 300, EVAL,
                                              loss="label", **options))

    learned = run("learned", base="rest", use_temperature=True)
    blind = run("blind", base="mean", use_temperature=False, use_context=False)  # a model ignoring its input
    rest_only = _closure(sim_dataset, evaluate_reference("start_rest", sim_dataset, None, EVAL))
    assert min(learned) >= 0.8, learned
    assert learned[0] > rest_only[0] + 0.1, (learned, rest_only)  # the temperature term is learned
    assert max(blind) < 0.5, blind


@pytest.mark.usefixtures("one_torch_thread")
def test_context_diffusion_learns_the_bias_and_needs_its_input(sim_dataset, tmp_path):
    """The residual drawn by DDIM: its sample mean closes the simulated gap; samples drawn without the
    input spread over the train split's residuals and close none of it."""
    sampled = EvaluationConfig(samples=8, samplers=["ddim"], gravity="recovered")

    def run(name, **options):
        return _closures(sim_dataset, _trained(sim_dataset, tmp_path / name, "context_diffusion", 600, sampled,
                                               lr=3e-3, **options))

    learned = run("learned", base="rest", use_temperature=True)
    blind = run("blind", base="mean", use_temperature=False, use_context=False)
    assert min(learned["mean"]) >= 0.8 and min(learned[""]) >= 0.7, learned
    assert max(blind["mean"]) < 0.5 and max(blind[""]) < 0.5, blind


def _context_batch(model, B: int = 5, T: int = 11):
    """A batch of B still windows (identity attitude, no motion) with random labels and a random context."""
    from training.data.batch import WindowBatch

    g = torch.Generator().manual_seed(3)
    eye = torch.eye(3).expand(B, 3, 3)
    z3 = torch.zeros(B, 3)
    return WindowBatch(imu=0.01 * torch.randn(B, T, 6, generator=g), bias=0.01 * torch.randn(B, T, 6, generator=g),
                       bias_std=torch.zeros(B, T, 6), dt_s=torch.full((B, T - 1), 0.01), start_R=eye, start_v=z3,
                       start_p=z3, end_R=eye, end_v=z3, end_p=z3,
                       context=torch.randn(B, model.net.context_size, generator=g))


def test_context_diffusion_losses_follow_the_forward_process():
    """Against the closed forms (DDPM eq. 4, DDIM eq. 9), with the noise estimate zeroed: the loss is the noise's
    mean square plus the integration of ``x0_hat = x_t / sqrt(alpha_bar)`` (on the base), each window weighted
    by ``min(alpha_bar / (1 - alpha_bar), 1)``."""
    import math

    from training.config import ModelConfig
    from training.data.normalizer import Normalizer
    from training.models.bias_model import BiasModel, integration_errors

    config = ModelConfig.for_preset("context_diffusion", "tiny", history_s=(), loss="both")
    model = BiasModel(config, Normalizer({k: [1.0] * 6 for k in ("imu_mean", "imu_std", "bias_mean", "bias_std")}))
    torch.nn.init.zeros_(model.net.denoiser[-1].weight)
    torch.nn.init.zeros_(model.net.denoiser[-1].bias)  # eps_hat = 0
    batch = _context_batch(model)
    B = len(batch)
    t = torch.tensor([0, 10, 200, 600, 999])
    noise = torch.randn(B, 6, generator=torch.Generator().manual_seed(7))
    loss = model.loss(batch, noise=noise, t=t)
    ab = torch.cumprod(1 - torch.linspace(1e-4, 0.02, 1000, dtype=torch.float64), 0)[t][:, None]
    base = batch.context[:, -6:].double()
    x0 = (batch.bias.double() - 1.0).mean(1) - base  # the normalised window mean (mean 1, std 1) on the base
    x_t = ab.sqrt() * x0 + (1 - ab).sqrt() * noise.double()
    bias = (x_t / ab.sqrt() + base) + 1.0  # x0_hat on the base, unnormalised
    rot, _, pos = integration_errors(batch.imu, bias, batch.dt_s, batch.start_R, batch.start_v, batch.start_p,
                                     batch.end_R, batch.end_v, batch.end_p, torch.tensor([0.0, 0.0, -9.81]))
    w = (ab / (1 - ab)).clamp(max=1)[:, 0]
    o = config.network
    expected = noise.double().square().mean() + (w * (rot / math.radians(o.rot_scale_deg) ** 2
                                                      + pos / o.pos_scale_m ** 2)).sum() / B
    torch.testing.assert_close(loss.double(), expected, rtol=2e-5, atol=0)


def test_context_diffusion_refuses_an_integration_loss_alone():
    from pipeline.errors import ConfigError
    from training.networks import ContextDiffusionOptions

    with pytest.raises(ConfigError, match="noise loss"):
        ContextDiffusionOptions(loss="integration")


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
