"""The gradient-norm spike guard (train.grad_clip): it clips spikes against the run's recent norms, not a scale."""

import math

import torch

from mtlx2neural.train.grad_clip import MIN_HISTORY, SPIKE_FACTOR, WINDOW, SpikeClip


def _step(clip: SpikeClip, norm: float):
    """One step whose single parameter's gradient has global norm ``norm``; returns (reported norm, clipped,
    the gradient's norm after the guard)."""
    p = torch.nn.Parameter(torch.zeros(4))
    p.grad = torch.full((4,), norm / 2.0)  # |(v, v, v, v)| = 2v
    reported, clipped = clip([p])
    return reported, clipped, float(p.grad.norm())


def test_a_spike_is_clipped_to_the_recent_median_times_the_factor():
    clip = SpikeClip()
    for _ in range(WINDOW):
        assert _step(clip, 1.0)[1] is False
    reported, clipped, after = _step(clip, 1000.0)
    assert clipped and math.isclose(reported, 1000.0, rel_tol=1e-5)
    assert math.isclose(after, SPIKE_FACTOR * 1.0, rel_tol=1e-5)
    # The spike recorded the cap, not its norm: the next cap is unchanged, so a second spike is clipped alike.
    assert math.isclose(_step(clip, 1000.0)[2], SPIKE_FACTOR, rel_tol=1e-5)


def test_a_run_whose_scale_is_large_is_not_clipped():
    """A near-mirror metal's norms (25-125 in `fast`) are its scale: within the factor of their median, nothing
    is clipped, where the old fixed cap of 10 clipped most of them."""
    clip = SpikeClip()
    g = torch.Generator().manual_seed(0)
    norms = (25.0 + 100.0 * torch.rand(500, generator=g)).tolist()
    assert not any(_step(clip, n)[1] for n in norms)


def test_the_first_steps_are_not_clipped_and_a_lasting_rise_is_followed():
    clip = SpikeClip()
    for _ in range(MIN_HISTORY - 1):
        _step(clip, 1.0)
    assert _step(clip, 1e6)[1] is False  # the scale is not known yet
    clip = SpikeClip()
    for _ in range(WINDOW):
        _step(clip, 1.0)
    flags = [_step(clip, 30.0)[1] for _ in range(WINDOW)]
    assert flags[0] and not any(flags[-WINDOW // 4:])  # clipped at first, then the cap has risen to the new scale


def test_a_non_finite_norm_is_reported_and_not_recorded():
    clip = SpikeClip()
    for _ in range(WINDOW):
        _step(clip, 1.0)
    cap = clip.cap
    reported, clipped, _ = _step(clip, float("nan"))
    assert math.isnan(reported) and not clipped
    assert clip.cap == cap
