"""``render.replayed_sampler.ReplayedSampler``: a render with replayed sampler draws is the render with the
sampler itself, bit for bit, and a call whose inputs differ from the recording is computed."""

from __future__ import annotations

import numpy as np
import torch
from closure_docs import closure_material

from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.renderer import render_scene
from mtlx2neural.render.replayed_sampler import ReplayedSampler


def _render(material, sampler):
    return render_scene(material, Sphere(), Camera(30.0, 20.0), [EnvironmentMap.sky()], res=24, spp=3, seed=2,
                        sampler=sampler)


def test_replayed_draws_render_as_the_sampler_does():
    reference = closure_material("conductor_bsdf", roughness=(0.15, 0.15))
    other = closure_material("oren_nayar_diffuse_bsdf", color=(0.6, 0.4, 0.3))
    replayed = ReplayedSampler(reference)
    replayed.start()
    first = _render(reference, replayed)
    assert replayed.replayed == 0 and len(replayed.calls) > 0
    replayed.start()
    second = _render(other, replayed)
    # every call of the second render repeats one of the first: all answered from the recording
    assert replayed.replayed == len(replayed.calls)
    np.testing.assert_array_equal(first, _render(reference, reference))
    np.testing.assert_array_equal(second, _render(other, reference))


def test_a_call_that_differs_is_computed():
    glossy = closure_material("conductor_bsdf", roughness=(0.3, 0.3))
    wi = torch.tensor([[0.0, 0.6, 0.8]]).expand(64, 3)
    u = torch.rand(64, 2, generator=torch.Generator().manual_seed(1))
    replayed = ReplayedSampler(glossy)
    replayed.start()
    with torch.no_grad():
        replayed.sample(wi, u)
        replayed.start()
        wo, _, pdf = replayed.sample(wi, u.flip(0))
        expected, _, density = glossy.sample(wi, u.flip(0))
    assert replayed.replayed == 0
    torch.testing.assert_close(wo, expected, rtol=0, atol=0)
    torch.testing.assert_close(pdf, density, rtol=0, atol=0)
