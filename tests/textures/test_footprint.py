"""Footprint-filtered targets and level sampling."""

from __future__ import annotations

import math

import MaterialX as mx
import numpy as np
import torch
from conftest import random_dirs, write_float_image

from mtlx2neural.graph import compile_material
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.textures.footprint import (
    footprint_targets,
    sample_levels,
    samples_for_level,
    stratified_gaussian,
)
from mtlx2neural.textures.parameter_stack import build_parameter_stack


def _stripes(path, res=32):
    """Vertical black/white stripes one texel wide: any footprint wider than a texel averages to grey."""
    img = np.zeros((res, res, 3), np.float32)
    img[:, ::2] = 1.0
    write_float_image(path, img)


def _diffuse_textured(path):
    doc = mx.createDocument()
    img = doc.addNode("image", "albedo", "color3")
    img.setInputValue("file", str(path), "filename")
    img.setInputValue("filtertype", "closest", "string")
    d = doc.addNode("oren_nayar_diffuse_bsdf", "d", "BSDF")
    d.setConnectedNode("color", img)
    s = doc.addNode("surface", "s", "surfaceshader")
    s.setConnectedNode("bsdf", d)
    doc.addMaterialNode("M", s)
    return compile_material(doc, "M")


def test_level_distribution_favours_fine_levels():
    g = torch.Generator().manual_seed(0)
    k = sample_levels(200_000, 6, rate=1.0, generator=g)
    freq = torch.bincount(k, minlength=6).double() / k.numel()
    expected = torch.exp(-torch.arange(6.0)).double()
    expected /= expected.sum()
    # 200k draws: binomial standard error < 0.0012 per level; 0.005 is ~4 sigma.
    torch.testing.assert_close(freq, expected, atol=5e-3, rtol=0)
    assert samples_for_level(0, 64) == 1 and samples_for_level(2, 64) == 16 and samples_for_level(5, 64) == 64


def _striped_material(tmp_path):
    path = tmp_path / "stripes.exr"
    _stripes(path)
    compiled = _diffuse_textured(path)
    return ReferenceMaterial(compiled), build_parameter_stack(compiled, resolution=(32, 32))


def test_coarse_footprint_averages_stripes(tmp_path):
    ref, stack = _striped_material(tmp_path)
    n = 4096
    g = torch.Generator().manual_seed(1)
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    wo = wi
    uv = torch.rand(n, 2, generator=g)
    # Level 0: one point, bilinearly interpolated between stripes -> spread over [0, 1]
    # (a uniform spread has standard deviation 0.29).
    fine = footprint_targets(ref, stack, wi, wo, uv, torch.zeros(n, dtype=torch.long), generator=g) * math.pi
    assert float(fine[:, 0].std()) > 0.2
    # Level 4 (16-texel footprint): close to the mean, 0.5. With 64 samples of a 0/1 variable
    # the standard error is 0.0625; 0.25 is four of them.
    coarse = footprint_targets(ref, stack, wi, wo, uv, torch.full((n,), 4, dtype=torch.long), generator=g) * math.pi
    assert float((coarse - 0.5).abs().max()) < 0.25
    assert abs(float(coarse.mean()) - 0.5) < 0.01
    # And the stack's own level 4 agrees with the footprint mean (box-filtered colour).
    colour = stack.sample(uv, 4)["d.color"]
    assert abs(float(colour.mean()) - 0.5) < 0.01


def test_targets_are_finite_for_random_queries(tmp_path):
    ref, stack = _striped_material(tmp_path)
    g = torch.Generator().manual_seed(2)
    n = 2000
    t = footprint_targets(ref, stack, random_dirs(n, 3), random_dirs(n, 4), torch.rand(n, 2, generator=g),
                          sample_levels(n, len(stack.levels), generator=g), generator=g)
    assert t.shape == (n, 3) and bool(torch.isfinite(t).all()) and bool((t >= 0).all())


def test_capped_grid_prefilters_level0_and_targets_use_the_true_material(tmp_path):
    """A grid 4x coarser than a 1-texel stripe texture: level 0 must hold the stripes' average
    (not a point sample of one stripe), and level-0 targets must average the real texture."""
    path = tmp_path / "stripes64.exr"
    _stripes(path, res=64)
    compiled = _diffuse_textured(path)
    ref = ReferenceMaterial(compiled)
    stack = build_parameter_stack(compiled, resolution=(16, 16))
    assert stack.texel_ratio == (4.0, 4.0)
    assert samples_for_level(0, 64, stack.texel_ratio) == 16
    # Each level-0 texel averages 4x4 sub-samples: two black and two white columns -> exactly 0.5
    # (float32 sums of 0/1 values are exact).
    colour = stack.texel_values(0)["d.color"]
    assert float((colour - 0.5).abs().max()) == 0.0
    n = 2048
    g = torch.Generator().manual_seed(3)
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    uv = torch.rand(n, 2, generator=g)
    t = footprint_targets(ref, stack, wi, wi, uv, torch.zeros(n, dtype=torch.long), 16, g) * math.pi
    # 16 points over ~4 stripes: each target is a mean of 0/1 values, so it varies (std of the
    # mean of 16 fair coins is 0.125), but the batch mean is 0.5 within 4 standard errors (0.011).
    assert abs(float(t[:, 0].mean()) - 0.5) < 0.011
    assert 0.05 < float(t[:, 0].std()) < 0.3


def test_stratified_footprint_points_are_gaussian_and_less_noisy():
    """Latin-hypercube normal points: one per equal-probability stratum per axis in every row,
    standard normal marginals, and a row mean of a step (a texel edge inside the footprint) with
    a quarter or less of the variance of independent draws, still unbiased."""
    g = torch.Generator().manual_seed(4)
    m, s = 20_000, 16
    x = stratified_gaussian(m, s, g)
    strata = torch.floor(torch.special.ndtr(x.double()) * s).long()  # float64: no rounding across a stratum edge
    assert torch.equal(strata.sort(dim=1).values, torch.arange(s).view(1, s, 1).expand(m, s, 2))
    flat = x.reshape(-1, 2).double()
    # 640k draws: the sample mean's standard error is 0.0013, the variance's 0.0018; 5 sigma.
    assert flat.mean(0).abs().max() < 0.007 and (flat.var(0) - 1).abs().max() < 0.01
    step = lambda p: (p[..., 0] > 0.3).double()  # noqa: E731  (P = 1 - Phi(0.3) = 0.382)
    lhs = step(x).mean(1)
    iid = step(torch.randn(m, s, 2, generator=g)).mean(1)
    # Mean of 20k row means: standard error 0.001 (iid rows); 5 sigma.
    assert abs(float(lhs.mean()) - 0.3821) < 0.005
    assert float(lhs.var()) < 0.25 * float(iid.var())


def test_one_call_gives_the_per_level_targets(tmp_path):
    """``one_call`` batches every level's points into one reference call: with a deterministic
    ``point_eval`` (the plain reference) and the same generator the offsets are the same draws, so
    the targets equal the per-level ones; on the capped grid (graph at the points) and on the native
    one (stack lookups), at levels with different point counts (1 to 16)."""
    path = tmp_path / "stripes64.exr"
    _stripes(path, res=64)
    compiled = _diffuse_textured(path)
    ref = ReferenceMaterial(compiled)
    for res in ((16, 16), (64, 64)):
        stack = build_parameter_stack(compiled, resolution=res)
        n = 1500
        g = torch.Generator().manual_seed(4)
        wi, wo = random_dirs(n, 5), random_dirs(n, 6)
        uv = torch.rand(n, 2, generator=g)
        level = sample_levels(n, len(stack.levels), rate=0.5, generator=g)
        assert len(torch.unique(level)) >= 4
        per_level = footprint_targets(ref, stack, wi, wo, uv, level, 16, torch.Generator().manual_seed(7))
        batched = footprint_targets(ref, stack, wi, wo, uv, level, 16, torch.Generator().manual_seed(7),
                                    one_call=True)
        assert bool((per_level > 0).any())
        # Same points, same values: only the float32 summation order differs (mean of up to 16
        # terms of size <= 1/pi), well under 1e-6.
        torch.testing.assert_close(batched, per_level, atol=1e-6, rtol=1e-5)
