"""verify/energy.py: the per-level directional-albedo ratio of a model against its reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mtlx2neural.verify.energy import energy_check


@pytest.fixture(scope="module")
def rough_metal(tmp_path_factory):
    """A textured metal, roughness 0.02-0.6 from a 16² texture (near-mirror texels included)."""
    import MaterialX as mx
    from conftest import write_float_image

    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial

    folder = tmp_path_factory.mktemp("metal")
    rng = np.random.default_rng(0)
    write_float_image(folder / "rough.exr", np.repeat(rng.uniform(0.02, 0.6, (16, 16, 1)), 3, -1).astype(np.float32))
    doc = mx.createDocument()
    img = doc.addNode("image", "rough", "float")
    img.setInputValue("file", str(folder / "rough.exr"), "filename")
    s = doc.addNode("standard_surface", "s", "surfaceshader")
    s.setInputValue("metalness", 1.0, "float")
    s.setInputValue("base_color", mx.Color3(0.9, 0.6, 0.3), "color3")
    s.setConnectedNode("specular_roughness", img)
    m = doc.addNode("surfacematerial", "M", "material")
    m.setConnectedNode("surfaceshader", s)
    return ReferenceMaterial(compile_material(doc, "M"))


class Scaled:
    """A material whose BRDF is ``scale`` times another's (the energy a darker model keeps), sampled
    as that one is."""

    def __init__(self, material, scale: float):
        self.material, self.scale = material, scale

    def eval(self, wi, wo, at=None):
        return self.scale * self.material.eval(wi, wo, at)

    def sample(self, wi, u, at=None):
        wo, weight, pdf = self.material.sample(wi, u, at)
        return wo, self.scale * weight, pdf

    def pdf(self, wi, wo, at=None):
        return self.material.pdf(wi, wo, at)

    def albedo(self, wi, at=None, samples=256, seed=0):
        return self.scale * self.material.albedo(wi, at, samples=samples, seed=seed)


class Blind:
    """A material whose sampler never finds the lobe it evaluates: it samples the cosine hemisphere
    *flipped below the horizon*, so every draw fails (a learned sampler that misses a sharp peak)."""

    def __init__(self, material):
        self.material = material

    def eval(self, wi, wo, at=None):
        return self.material.eval(wi, wo, at)

    def sample(self, wi, u, at=None):
        wo = torch.stack([u[:, 0] - 0.5, u[:, 1] - 0.5, -torch.ones_like(u[:, 0])], -1)
        return wo / wo.norm(dim=-1, keepdim=True), torch.zeros_like(wo), torch.zeros_like(wo[:, 0])

    def pdf(self, wi, wo, at=None):
        return torch.zeros_like(wo[:, 0])


def test_the_reference_keeps_its_own_energy(rough_metal):
    """Against itself (point albedo at uv against the footprint mean around it) every level's ratio is
    1 within 7 %: Monte Carlo noise of a near-mirror texel's albedo (64 x 8 Sobol samples per row) and
    the footprint's spread of a random roughness texture, measured 1.00-1.03."""
    chk = energy_check(rough_metal, rough_metal, (16, 16), 5, texels=32, seed=1)
    assert len(chk.levels) == 5 and all(0.5 < lv.reference < 1.0 for lv in chk.levels)
    for lv in chk.levels:
        assert abs(lv.ratio - 1.0) < 0.07, (lv.level, lv.ratio)
        assert set(lv.ratio_by_view) == {0.0, 30.0, 60.0, 80.0}


def test_a_darker_model_is_caught_at_every_level(rough_metal):
    chk = energy_check(rough_metal, Scaled(rough_metal, 0.6), (16, 16), 3, texels=32, seed=2)
    assert abs(chk.min_ratio - 0.6) < 0.05 and chk.worst_level in (0, 1, 2)
    data = chk.to_json()
    assert len(data["by_level"]) == 3 and data["min_ratio"] == chk.min_ratio


class GrazingBright:
    """A material that reflects ``scale`` times another's BRDF where the viewer is more than 72.5 degrees
    from the normal (wi.z < 0.3) and the same BRDF elsewhere, sampled as that one is."""

    def __init__(self, material, scale: float):
        self.material, self.scale = material, scale

    def eval(self, wi, wo, at=None):
        grazing = (wi[:, 2:3] < 0.3).to(wi.dtype)
        return (1.0 + (self.scale - 1.0) * grazing) * self.material.eval(wi, wo, at)

    def sample(self, wi, u, at=None):
        return self.material.sample(wi, u, at)

    def pdf(self, wi, wo, at=None):
        return self.material.pdf(wi, wo, at)


def test_the_views_show_what_the_levels_pool(rough_metal):
    """A model 1.5x too bright at the 80-degree view only: that view's ratio is 1.5 and the others 1, each
    within 0.07 (the Monte Carlo noise of the self-check above), while every level's ratio, which pools the
    four views, stays within 1.0-1.3; the record's JSON lists the views' ratios in ``view_degrees``' order."""
    chk = energy_check(rough_metal, GrazingBright(rough_metal, 1.5), (16, 16), 3, texels=32, seed=1)
    views = chk.by_view
    assert set(views) == {0.0, 30.0, 60.0, 80.0}
    assert abs(views[80.0] - 1.5) < 0.07 and all(abs(views[d] - 1.0) < 0.07 for d in (0.0, 30.0, 60.0))
    assert all(1.0 < lv.ratio < 1.3 for lv in chk.levels)
    assert chk.to_json()["by_view"] == [views[d] for d in chk.view_degrees]


def test_a_black_reference_has_no_ratio(rough_metal):
    black = Scaled(rough_metal, 0.0)
    chk = energy_check(black, rough_metal, (16, 16), 1, texels=8, seed=3)
    assert np.isnan(chk.levels[0].ratio) and np.isnan(chk.min_ratio) and chk.worst_level is None
    torch.testing.assert_close(torch.tensor(chk.levels[0].reference), torch.tensor(0.0))


def test_a_brighter_model_is_caught_too(rough_metal):
    chk = energy_check(rough_metal, Scaled(rough_metal, 1.5), (16, 16), 2, texels=32, seed=4)
    assert abs(chk.max_ratio - 1.5) < 0.1 and chk.brightest_level in (0, 1)
    assert chk.to_json()["max_ratio"] == chk.max_ratio


def test_energy_the_models_own_sampler_misses_is_still_counted(rough_metal):
    """A model whose sampler never draws its lobe keeps all of its energy: the check's mixture of the
    model's, the reference's and the cosine sampler still finds it (within the 7 % of the first test),
    where the model's own estimate (``albedo``, its sampler alone) would read 0."""
    chk = energy_check(rough_metal, Blind(rough_metal), (16, 16), 2, texels=32, seed=5)
    for lv in chk.levels:
        assert abs(lv.ratio - 1.0) < 0.07, (lv.level, lv.ratio)
