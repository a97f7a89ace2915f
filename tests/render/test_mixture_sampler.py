"""``render.mixture_sampler.MixtureSampler``: its samples follow its density (chi-square), and a mixture of one
material samples exactly as that material does."""

from __future__ import annotations

import math

import torch
from closure_docs import closure_material
from sampler_checks import sampler_chi2

from mtlx2neural.render.mixture_sampler import MixtureSampler

WI = torch.tensor([[math.sin(0.5) * 0.8, math.sin(0.5) * 0.6, math.cos(0.5)]])


def test_a_diffuse_and_a_glossy_mixture_samples_its_density():
    mixture = MixtureSampler(closure_material("oren_nayar_diffuse_bsdf", color=(0.5, 0.5, 0.5)),
                             closure_material("conductor_bsdf", roughness=(0.2, 0.2)))
    with torch.no_grad():
        result = sampler_chi2(mixture, WI, test_count=1)
    assert result.passed, result.message


def test_a_mixture_of_one_is_that_material():
    glossy = closure_material("conductor_bsdf", roughness=(0.3, 0.1))
    u = torch.rand(512, 2, generator=torch.Generator().manual_seed(3))
    wi = WI.expand(512, 3)
    with torch.no_grad():
        wo, _, pdf = glossy.sample(wi, u)
        wo1, _, pdf1 = MixtureSampler(glossy).sample(wi, u)
    # the same uniform numbers (u0 * 1 - 0 = u0): the same directions and densities, to float rounding
    torch.testing.assert_close(wo1, wo, rtol=0, atol=1e-6)
    torch.testing.assert_close(pdf1, pdf, rtol=1e-5, atol=1e-6)


def test_each_row_is_its_picked_materials_sample():
    diffuse = closure_material("oren_nayar_diffuse_bsdf", color=(0.5, 0.5, 0.5))
    glossy = closure_material("conductor_bsdf", roughness=(0.2, 0.2))
    u = torch.rand(256, 2, generator=torch.Generator().manual_seed(5))
    wi = WI.expand(256, 3)
    with torch.no_grad():
        wo, _, pdf = MixtureSampler(diffuse, glossy).sample(wi, u)
        pick = (u[:, 0] * 2).floor()
        rescaled = torch.stack([u[:, 0] * 2 - pick, u[:, 1]], -1)
        expected = torch.where((pick == 0)[:, None], diffuse.sample(wi, rescaled)[0], glossy.sample(wi, rescaled)[0])
        density = (diffuse.pdf(wi, expected) + glossy.pdf(wi, expected)) / 2
    # each material draws only its own rows, from the same numbers: the same directions, to float rounding
    assert 0 < int((pick == 0).sum()) < 256
    torch.testing.assert_close(wo, expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(pdf, density, rtol=1e-5, atol=1e-6)
