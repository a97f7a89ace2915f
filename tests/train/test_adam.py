"""The project's Adam (mtlx2neural.train.adam) against torch.optim.Adam: the same parameters bit for bit."""

from __future__ import annotations

import torch

from mtlx2neural.train.adam import Adam


def _params(seed: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=g).requires_grad_() for shape in ((7, 5), (5,), (3, 4, 2))]


def _run(make, steps: int = 25, reload_at: int | None = None) -> list[torch.Tensor]:
    """Steps of a small regression with a learning rate that changes every step; the second parameter
    gets no gradient on every third step (Adam then skips it, and its step count falls behind)."""
    params = _params(0)
    opt = make(params)
    g = torch.Generator().manual_seed(1)
    for step in range(steps):
        for group in opt.param_groups:
            group["lr"] = 5e-3 * 0.9 ** step
        opt.zero_grad(set_to_none=True)
        x = torch.randn(16, 7, generator=g)
        loss = ((x @ params[0] + params[1]) ** 2).mean() + params[2].abs().sum() * 1e-2
        loss.backward()
        if step % 3 == 0:
            params[1].grad = None
        opt.step()
        if step == reload_at:  # a checkpoint: the state dict into a fresh optimiser
            state = opt.state_dict()
            opt = make(params)
            opt.load_state_dict(state)
    return [p.detach().clone() for p in params]


def test_matches_torch_adam_bit_for_bit():
    ours = _run(lambda p: Adam(p, lr=5e-3, betas=(0.9, 0.999), eps=1e-7))
    theirs = _run(lambda p: torch.optim.Adam(p, lr=5e-3, betas=(0.9, 0.999), eps=1e-7))
    for a, b in zip(ours, theirs):
        assert torch.equal(a, b)
    assert not torch.equal(ours[0], _params(0)[0])  # the parameters moved


def test_a_state_dict_round_trips_and_loads_from_torch():
    """Reloaded mid-run (ours into ours, torch's into ours) the run continues as if uninterrupted."""
    straight = _run(lambda p: Adam(p, lr=5e-3, eps=1e-7))
    reloaded = _run(lambda p: Adam(p, lr=5e-3, eps=1e-7), reload_at=10)
    for a, b in zip(straight, reloaded):
        assert torch.equal(a, b)
    params = _params(0)
    theirs = torch.optim.Adam(params, lr=5e-3, eps=1e-7)
    params[0].sum().backward()
    theirs.step()
    ours = Adam(params, lr=5e-3, eps=1e-7)
    ours.load_state_dict(theirs.state_dict())
    assert torch.equal(ours.state[params[0]]["exp_avg"], theirs.state[params[0]]["exp_avg"])
    assert float(ours.state[params[0]]["step"]) == 1.0 and params[1] not in ours.state
