"""The learned sampler's analytic proxy: chi-square and normalisation for random parameters."""

from __future__ import annotations

import math

import pytest
import torch

from mtlx2neural.model import proxy
from mtlx2neural.verify.chi2 import chi2_test, pdf_integral

CASES = {
    "isotropic_centred": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.0],
    "anisotropic_correlated": [-1.0, 0.8, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    "non_centred": [-0.5, -0.2, -0.6, 0.4, -0.3, 0.5, 0.2, 0.3, -0.3],
    "mostly_diffuse_tilted": [0.3, 0.3, 0.0, 0.0, 0.0, -0.6, 0.4, -2.0, 2.0],
}
N_TESTS = len(CASES) * 2


def _params(raw, n):
    return proxy.ProxyParams.from_network(torch.tensor([raw], dtype=torch.float64).expand(n, 9))


def _wi(deg):
    t = math.radians(deg)
    return torch.tensor([[math.sin(t) * 0.6, math.sin(t) * 0.8, math.cos(t)]], dtype=torch.float64)


@pytest.mark.parametrize("deg", [15.0, 60.0])
@pytest.mark.parametrize("name", list(CASES))
def test_proxy_sampler_chi2(name, deg):
    wi = _wi(deg)

    def sample_fn(u):
        n = u.shape[0]
        wo = proxy.sample(wi.expand(n, 3), _params(CASES[name], n), u.double())
        return wo, torch.isfinite(wo).all(-1)

    def pdf_fn(wo):
        n = wo.shape[0]
        return proxy.pdf(wi.expand(n, 3), wo.double(), _params(CASES[name], n))

    r = chi2_test(sample_fn, pdf_fn, sample_count=100_000, test_count=N_TESTS, seed=3)
    assert r.passed, r.message


@pytest.mark.parametrize("name", list(CASES))
def test_proxy_pdf_integrates_to_one(name):
    wi = _wi(40.0)
    total = pdf_integral(lambda wo: proxy.pdf(wi.expand(wo.shape[0], 3), wo.double(),
                                              _params(CASES[name], wo.shape[0])), resolution=512)
    # Quadrature of a smooth mixture on a 512-point grid: better than 1%.
    assert abs(total - 1.0) < 0.01, total


def test_activations_and_extremes_stay_finite():
    raw = torch.tensor([[1e6, -1e6, 1e6, 50.0, -50.0, 50.0, -50.0, 80.0, -80.0],
                        [0.0] * 9], dtype=torch.float32)
    p = proxy.ProxyParams.from_network(raw)
    assert bool((p.alpha >= 1e-4 - 1e-9).all()) and bool((p.alpha <= 1.0 + 1e-4 + 1e-6).all())
    assert bool((p.rho.abs() <= 1.0).all())
    wi = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1e-8]])
    wi = wi / wi.norm(dim=-1, keepdim=True)
    u = torch.tensor([[0.999999, 0.5], [0.0, 0.0]])
    wo = proxy.sample(wi, p, u)
    assert bool(torch.isfinite(wo).all()) and bool(torch.isfinite(proxy.pdf(wi, wo, p)).all())
