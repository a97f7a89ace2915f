"""Trained quality guarded by bounds: a short seeded run on a small textured material must reach an HDR FLIP
and a held-out BRDF error measured from two seeds, with a margin well under 2x, so a regression that
doubles the error (or a broken schedule: a tenth of the learning rate, a quarter of the steps) fails.

The measurements behind the bounds, and the command that repeats them, are in
docs/history/paper-choices-2026-12-02.md ("Quality guard")."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer

# The guard's run: the fast preset's settings, shortened (400 steps of 128 rows, 4 footprint points per
# target): about 75-100 s of one core.
GUARD_RUN = {"iterations": 400, "batch": 128, "footprint_samples": 4}
# Measured at GUARD_RUN with seeds 1 and 2 (docs/history/paper-choices-2026-12-02.md, "Quality guard"):
# mean HDR FLIP of the three default views 0.398 / 0.394, held-out log error 0.341 / 0.329; a quarter of
# the steps gives FLIP 0.449, held-out 0.476, a tenth of the learning rate 0.446 / 0.469 (seed 1); an
# untrained network ~0.8 held-out. Bounds: held-out 20% and FLIP 10% above the worse seed (FLIP moves
# less between a good and a broken run: 0.39 against 0.45), room for thread-count and platform float
# noise, while an error twice the measured one, a quarter of the steps or a tenth of the learning rate
# is outside them. With every level's footprint points in one reference call per step (since 2026-12-03)
# seed 1 gives 0.340 / 0.330. Over seeds 1-6 the run is bimodal either way: FLIP 0.24-0.40 and held-out
# 0.30-0.35 at four or five seeds, ~0.44 / 0.44-0.46 at the others (seed 5 both ways, seed 2 with one
# call), so the guard's seed is fixed and a seed change needs the bounds re-measured
# (docs/history/time-to-quality-2026-12-03.md, "footprint_one_call by default"; the switch is gone since).
FLIP_BOUND = 0.44
HELD_OUT_BOUND = 0.41
HELD_OUT_EPS = 0.01  # log(x + eps): f * cos below ~0.01 counts as black (the dark texels' diffuse is ~0.02)


def textured_dielectric(directory):
    """A small textured material with detail the footprint filter keeps: 16x16 textures of smooth periodic
    waves (one period across the texture), base colour 0.1-0.85 per channel (phase-shifted per channel),
    specular roughness 0.25-0.6, on standard_surface's default dielectric. Deterministic."""
    import MaterialX as mx
    from conftest import write_float_image

    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial

    y, x = np.meshgrid(np.arange(16) / 16, np.arange(16) / 16, indexing="ij")
    wave = [0.5 + 0.5 * np.sin(2 * np.pi * (x + phase) + np.cos(2 * np.pi * y)) for phase in (0.0, 0.33, 0.67)]
    write_float_image(directory / "col.exr", (0.1 + 0.75 * np.stack(wave, -1)).astype(np.float32))
    rough = 0.25 + 0.35 * (0.5 + 0.5 * np.cos(2 * np.pi * (y - x)))
    write_float_image(directory / "rough.exr", np.repeat(rough[..., None], 3, -1).astype(np.float32))
    doc = mx.createDocument()
    col = doc.addNode("image", "col", "color3")
    col.setInputValue("file", str(directory / "col.exr"), "filename")
    img = doc.addNode("image", "rough", "float")
    img.setInputValue("file", str(directory / "rough.exr"), "filename")
    s = doc.addNode("standard_surface", "s", "surfaceshader")
    s.setConnectedNode("base_color", col)
    s.setConnectedNode("specular_roughness", img)
    doc.addMaterialNode("M", s)
    return ReferenceMaterial(compile_material(doc, "M"))


def held_out_error(reference, model, n: int = 4096, seed: int = 123) -> float:
    """Mean |log(ref + eps) - log(model + eps)| over ``n`` held-out (uv, wi, wo): uv uniform, wi and wo
    uniform on the hemisphere (cos >= 0.05), f * cos per channel at the finest level, local frame."""
    g = torch.Generator().manual_seed(seed)

    def hemisphere(k):
        w = torch.nn.functional.normalize(torch.randn(k, 3, generator=g, dtype=torch.float64), dim=-1)
        return torch.cat([w[:, :2], w[:, 2:].abs().clamp_min(0.05)], -1)

    wi, wo, uv = hemisphere(n), hemisphere(n), torch.rand(n, 2, generator=g, dtype=torch.float64)
    with torch.no_grad():
        a = reference.eval(wi, wo, ShadingPoint(uv=uv)).float()
        b = model.eval(wi, wo, ShadingPoint(uv=uv.float())).float()
    return float((torch.log(a + HELD_OUT_EPS) - torch.log(b + HELD_OUT_EPS)).abs().mean())


def mean_flip(reference, model, texels) -> float:
    """Mean HDR FLIP over render.renderer's three default views (48 px, 8 spp, seeded per view)."""
    from mtlx2neural.render.renderer import compare

    return float(np.mean([r["flip"] for r in compare(reference, model, texels, res=48, spp=8)]))


def train_and_measure(reference, stack, out_dir, seed: int = 1, **overrides) -> dict:
    """Train the guard's run (GUARD_RUN, then ``overrides``) and return its FLIP and held-out error."""
    cfg = preset("fast", seed=seed, **{**GUARD_RUN, **overrides})
    model = Trainer(reference, stack, cfg, out_dir).run(progress=False)
    return {"flip": mean_flip(reference, model, stack.resolution), "held_out": held_out_error(reference, model)}


@pytest.fixture(scope="module")
def dielectric(tmp_path_factory):
    ref = textured_dielectric(tmp_path_factory.mktemp("quality"))
    return ref, build_parameter_stack(ref.compiled)


def test_short_training_meets_the_measured_quality_bounds(dielectric, tmp_path):
    pytest.importorskip("flip_evaluator", reason="HDR FLIP needs the flip-evaluator package")
    ref, stack = dielectric
    assert stack.resolution == (16, 16)
    got = train_and_measure(ref, stack, tmp_path, seed=1)
    assert got["flip"] < FLIP_BOUND, got
    assert got["held_out"] < HELD_OUT_BOUND, got


def test_albedo_target_follows_the_texture(dielectric, tmp_path):
    """The albedo head's target is the reference's albedo in the row's own footprint: two texels of
    different base colour get different targets, each matching the albedo averaged over that footprint
    (Gaussian, half a texel at level 0)."""
    from mtlx2neural.textures.footprint import SIGMA_TEXELS

    ref, stack = dielectric
    tr = Trainer(ref, stack, preset("fast", iterations=1, seed=5, albedo_head=True), tmp_path)
    n = 4000
    wi = torch.tensor([[0.3, 0.2, 0.93]]).expand(n, 3)
    level = torch.zeros(n, dtype=torch.long)
    g = torch.Generator().manual_seed(0)
    means, truth = [], []
    for uv in ((0.03125, 0.03125), (0.53125, 0.28125)):  # texel centres (0,0) and (8,4) of the 16x16 grid
        uvs = torch.tensor([uv]).expand(n, 2)
        means.append(tr.albedo_targets(wi, uvs, level).mean(0))
        pts = uvs[:256].double() + SIGMA_TEXELS / 16 * torch.randn(256, 2, generator=g, dtype=torch.float64)
        truth.append(ref.albedo(wi[:256].double(), ShadingPoint(uv=pts), samples=64).float().mean(0))
    # 4000 one-sample estimates: relative standard error ~1-2% (diffuse-dominated weights, the footprint's
    # colour spread); the reference's 256 x 64 estimate is tighter. The two texels differ by far more.
    for m, t in zip(means, truth):
        assert torch.allclose(m, t, rtol=0.06, atol=0.01), (m, t)
    assert (means[0] - means[1]).abs().max() > 0.1, means


@pytest.mark.slow  # the guard's run with the albedo head: ~80-160 s of one core
def test_trained_albedo_head_follows_the_texture(dielectric, tmp_path):
    """After the guard's run with the albedo head (seed 1), its output follows the texture: mean absolute
    error against the reference's Monte Carlo albedo below 0.1 at 256 held-out (uv, wi), and the two texels
    of test_albedo_target_follows_the_texture (reference albedo 0.78/0.55/0.16 and 0.63/0.14/0.73 at
    wi = (0.3, 0.2, 0.93)) more than 0.2 apart in some channel. Measured (1024 points, seeds 1 and 2,
    docs/history/paper-choices-2026-12-03.md): error 0.031-0.066 at seeds 1-4; the albedo as 3 more outputs
    of the decoder MLP, 0.12-0.21 at three seeds of four, fails the bound; after 120 steps the two texels
    differ by 0.02."""
    ref, stack = dielectric
    cfg = preset("fast", seed=1, albedo_head=True, **GUARD_RUN)
    model = Trainer(ref, stack, cfg, tmp_path).run(progress=False)
    g = torch.Generator().manual_seed(321)
    w = torch.nn.functional.normalize(torch.randn(256, 3, generator=g, dtype=torch.float64), dim=-1)
    wi = torch.nn.functional.normalize(torch.cat([w[:, :2], w[:, 2:].abs().clamp_min(0.05)], -1), dim=-1)
    uv = torch.rand(256, 2, generator=g, dtype=torch.float64)
    fine = torch.zeros(256, dtype=torch.long)
    with torch.no_grad():
        truth = ref.albedo(wi, ShadingPoint(uv=uv), samples=128).float()  # MC std ~0.01 per point
        got = model.decoder.predict_albedo(model.latents.fetch(uv.float(), fine), wi.float())
        probes = model.decoder.predict_albedo(
            model.latents.fetch(torch.tensor([[0.03125, 0.03125], [0.53125, 0.28125]]), fine[:2]),
            torch.tensor([[0.3, 0.2, 0.93]]).expand(2, 3))
    err = float((got - truth).abs().mean())
    assert err < 0.1, err
    assert float((probes[0] - probes[1]).abs().max()) > 0.2, probes
