"""The noise scheduler against closed forms and against diffusers' schedulers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from training.config import Sampler
from training.models.scheduler import ClipCount, NoiseScheduler

diffusers = pytest.importorskip("diffusers")  # a test dependency (pyproject 'test' extra); guard only


def test_alpha_bar_closed_form():
    s = NoiseScheduler()
    betas = [1e-4 + (0.02 - 1e-4) * i / 999 for i in range(1000)]
    expected = math.prod(1.0 - b for b in betas)
    assert float(s.alphas_cumprod[999]) == pytest.approx(expected, rel=1e-5)  # float32 schedule
    assert float(s.alphas_cumprod[999]) == pytest.approx(4.04e-5, rel=5e-3)


def test_ddim_with_oracle_noise_returns_x0_exactly():
    s = NoiseScheduler()
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(4, 50, 6, generator=g, dtype=torch.float64)
    eps_true = torch.randn(x0.shape, generator=g, dtype=torch.float64)
    timesteps = s.set_timesteps(25, Sampler.DDIM)
    assert timesteps.tolist() == list(range(960, -1, -40))
    x = s.add_noise(x0, eps_true, torch.full((4,), int(timesteps[0])))
    for t in timesteps.tolist():
        # the oracle: the noise that, with x0, gives the current x_t
        ab = s.alphas_cumprod[t].double()
        eps = (x - ab.sqrt() * x0) / (1 - ab).sqrt()
        x = s.ddim_step(eps, t, x)
    assert torch.allclose(x, x0, atol=1e-12, rtol=0)


def _ours_and_theirs(kind: str, steps: int):
    ours = NoiseScheduler()
    common = dict(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02, beta_schedule="linear",
                  clip_sample=False, prediction_type="epsilon")
    if kind == "ddim":
        theirs = diffusers.DDIMScheduler(**common, set_alpha_to_one=True, steps_offset=0,
                                         timestep_spacing="leading")
        ours.set_timesteps(steps, Sampler.DDIM)
    else:
        theirs = diffusers.DDPMScheduler(**common, variance_type="fixed_small", timestep_spacing="leading")
        ours.set_timesteps(steps, Sampler.DDPM)
    theirs.set_timesteps(steps)
    assert ours.timesteps.tolist() == theirs.timesteps.tolist()
    return ours, theirs


@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
def test_ddim_step_equals_diffusers(eta):
    ours, theirs = _ours_and_theirs("ddim", 25)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(3, 40, 6, generator=g)
    for t in ours.timesteps.tolist():
        eps = torch.randn(x.shape, generator=g)
        mine = ours.ddim_step(eps, t, x, eta=eta, generator=torch.Generator().manual_seed(t))
        ref = theirs.step(eps, t, x, eta=eta, generator=torch.Generator().manual_seed(t)).prev_sample
        assert torch.allclose(mine, ref, atol=1e-6, rtol=0), t
        x = ref


@pytest.mark.parametrize("kind", ["ddim", "ddpm"])
def test_clipped_steps_equal_diffusers_clip_sample(kind):
    """clip_x0 is diffusers' clip_sample / clip_sample_range: x0_hat clamped, eps kept."""
    ours, _ = _ours_and_theirs(kind, 25)
    common = dict(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02, beta_schedule="linear",
                  clip_sample=True, clip_sample_range=3.0, prediction_type="epsilon", timestep_spacing="leading")
    theirs = (diffusers.DDIMScheduler(**common, set_alpha_to_one=True, steps_offset=0) if kind == "ddim"
              else diffusers.DDPMScheduler(**common, variance_type="fixed_small"))
    theirs.set_timesteps(25)
    g = torch.Generator().manual_seed(2)
    x = 4.0 * torch.randn(3, 40, 6, generator=g)
    clipped = 0
    for t in ours.timesteps.tolist():
        eps = torch.randn(x.shape, generator=g)
        clipped += int((ours.predict_x0(eps, t, x).abs() > 3.0).any())
        if kind == "ddim":
            mine = ours.ddim_step(eps, t, x, clip_x0=3.0)
            ref = theirs.step(eps, t, x, eta=0.0).prev_sample
        else:
            mine = ours.ddpm_step(eps, t, x, generator=torch.Generator().manual_seed(t), clip_x0=3.0)
            ref = theirs.step(eps, t, x, generator=torch.Generator().manual_seed(t)).prev_sample
        assert torch.allclose(mine, ref, atol=1e-5, rtol=1e-6), t
        x = ref
    assert clipped > 10  # the clamp was active on most steps, so the comparison covers it


def test_clipping_keeps_an_oracle_sample_inside_the_range():
    """With the true noise, DDIM still returns x0 when x0 lies inside the clip range."""
    s = NoiseScheduler()
    s.set_timesteps(25, Sampler.DDIM)
    g = torch.Generator().manual_seed(3)
    x0 = torch.rand(2, 30, 6, generator=g) * 4 - 2  # within [-2, 2]
    noise = torch.randn(x0.shape, generator=g)
    x = s.add_noise(x0, noise, torch.full((2,), int(s.timesteps[0])))
    for t in s.timesteps.tolist():
        x = s.ddim_step(noise, t, x, clip_x0=3.0)
    assert torch.allclose(x, x0, atol=1e-4)


def test_per_channel_clip_bounds_and_their_count():
    """A (lo, hi) clip clamps each channel to its own bounds (numpy's clip); the count marks the clamped values."""
    s = NoiseScheduler()
    s.set_timesteps(10, Sampler.DDIM)
    g = torch.Generator().manual_seed(5)
    x, eps = torch.randn(3, 20, 6, generator=g) * 3, torch.randn(3, 20, 6, generator=g)
    lo, hi = torch.tensor([-1.0, -2.0, -0.5, -4.0, -0.1, 0.5]), torch.tensor([1.0, 0.5, 3.0, 4.0, 0.1, 9.0])
    t = int(s.timesteps[3])
    x0 = s.predict_x0(eps, t, x).double().numpy()
    ref_x0 = np.clip(x0, lo.double().numpy(), hi.double().numpy())
    ab_prev = float(s.alphas_cumprod[t - 100])
    mask = torch.zeros(x.shape, dtype=torch.bool)
    got = s.ddim_step(eps, t, x, clip_x0=(lo, hi), clipped=mask)
    np.testing.assert_allclose(got.numpy(), math.sqrt(ab_prev) * ref_x0 + math.sqrt(1 - ab_prev) * eps.numpy(),
                               rtol=1e-5, atol=1e-5)
    assert np.array_equal(mask.numpy(), ref_x0 != x0) and 0 < mask.sum() < mask.numel()

    count = ClipCount()
    s.sample(lambda xt, tt: eps, (3, 20, 6), steps=10, generator=g, clip_x0=(lo, hi), clip_count=count)
    on_bound, any_step = count.fractions()
    assert count.values == 60 and all(0 <= a <= b <= 1 for a, b in zip(on_bound, any_step))


@pytest.mark.parametrize("steps", [1000, 25])
def test_ddpm_step_equals_diffusers(steps):
    ours, theirs = _ours_and_theirs("ddpm", steps)
    g = torch.Generator().manual_seed(2)
    x = torch.randn(2, 30, 6, generator=g)
    for t in ours.timesteps.tolist()[:: max(1, steps // 50)] + [0]:
        eps = torch.randn(x.shape, generator=g)
        mine = ours.ddpm_step(eps, t, x, generator=torch.Generator().manual_seed(t))
        ref = theirs.step(eps, t, x, generator=torch.Generator().manual_seed(t)).prev_sample
        assert torch.allclose(mine, ref, atol=1e-6, rtol=0), t


def test_add_noise_equals_diffusers():
    ours, theirs = _ours_and_theirs("ddpm", 1000)
    g = torch.Generator().manual_seed(3)
    x0, noise = torch.randn(8, 20, 6, generator=g), torch.randn(8, 20, 6, generator=g)
    t = torch.tensor([0, 1, 10, 100, 500, 900, 998, 999])
    assert torch.allclose(ours.add_noise(x0, noise, t), theirs.add_noise(x0, noise, t), atol=1e-6, rtol=0)


def test_released_sampler_visits_t_below_steps_and_returns_clipped_x0():
    """The published code's DDIM: t = S-1..0 and each step is the clipped x0 estimate."""
    s = NoiseScheduler()
    assert s.set_timesteps(25, Sampler.RELEASED).tolist() == list(range(24, -1, -1))
    g = torch.Generator().manual_seed(4)
    x, eps = torch.randn(2, 10, 6, generator=g), torch.randn(2, 10, 6, generator=g)
    ab = s.alphas_cumprod[24].float()
    x0 = (x - (1 - ab).sqrt() * eps) / ab.sqrt()
    assert torch.allclose(s.released_step(eps, 24, x), x0.clamp(-1, 1), atol=1e-6)
    # the released DDIM formula with its alpha_bar_prev = 1 (t_prev = 24 - 1000 // 25 < 0) is the same
    ref = diffusers.DDIMScheduler(clip_sample=True, set_alpha_to_one=True)
    ref.set_timesteps(25)
    ref.num_inference_steps = 25  # t_prev = t - 40 as in the released code
    assert torch.allclose(ref.step(eps, 24, x, eta=0.0).prev_sample, x0.clamp(-1, 1), atol=1e-6)
