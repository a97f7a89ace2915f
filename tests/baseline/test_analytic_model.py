"""The analytic baseline (Lambert + GGX, fitted): parameter recovery, numerics, UsdPreviewSurface export."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from materials import document, standard_surface  # noqa: E402  (shared documents)

import mtlx2neural as m2n
from mtlx2neural.baseline.analytic_model import (
    CHANNELS,
    AnalyticMaterial,
    author_preview_surface,
    fit_analytic,
    write_preview_textures,
)
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.render.renderer import compare
from mtlx2neural.textures.parameter_stack import build_parameter_stack

BASE = (0.6, 0.3, 0.1)
MTLX = document(standard_surface("M", base_color=BASE, specular_roughness=0.4, metalness=0.0))


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    path = tmp_path_factory.mktemp("analytic") / "m.mtlx"
    path.write_text(MTLX)
    ref = m2n.load_reference(path, "M")
    stack = build_parameter_stack(ref.compiled, resolution=(1, 1))
    return ref, fit_analytic(ref, stack, iterations=150, batch=2048, seed=0)


def test_fit_recovers_a_known_material(fitted):
    """standard_surface (metalness 0, specular_roughness 0.4, base colour BASE): the fit's roughness is
    within 0.03 and its base colour within 0.05 (MaterialX darkens the diffuse base by the specular
    layer's directional albedo, ~4%, which Lambert + GGX folds into the base colour: it comes out
    slightly below BASE); metalness below 0.1 and dielectric specular 0.5 (F0 0.04, IOR 1.5) +- 0.15."""
    _, model = fitted
    p = {k: v.detach()[0] for k, v in model.parameters_at().items()}
    assert abs(float(p["roughness"]) - 0.4) < 0.03
    assert torch.allclose(p["base"], torch.tensor(BASE), atol=0.05), p["base"]
    assert float(p["metalness"]) < 0.1
    assert abs(float(p["specular"]) - 0.5) < 0.15
    assert float(p["normal"][2]) > 0.999
    assert model.final_loss < 0.06


def test_compare_renders_the_analytic_model(fitted):
    ref, model = fitted
    out = compare(ref, model, (1, 1), res=16, spp=1)
    assert len(out) == 3 and all(math.isfinite(e["flip"]) and e["flip"] < 0.2 for e in out)


def test_eval_is_finite_at_grazing_and_below_horizon():
    g = torch.Generator().manual_seed(1)
    model = AnalyticMaterial((4, 4))
    with torch.no_grad():  # extreme channels: black/white, roughness at its floor/1, steep normals
        for lv in model.maps.levels:
            lv.copy_(torch.randn(lv.shape, generator=g) * 30)
    n = 4096
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wi[:64, 2], wo[64:128, 2] = 0.0, 0.0  # exactly grazing
    wi[128:192] = torch.tensor([1.0, 0.0, 0.0])
    wo[128:192] = torch.tensor([-1.0, 0.0, 0.0])  # grazing and opposite: wi + wo = 0
    wi[192:256] = wo[192:256] = torch.tensor([0.0, 0.0, 1.0])  # mirror configuration
    uv, lod, u = torch.rand(n, 2, generator=g), torch.rand(n, generator=g) * 4, torch.rand(n, generator=g)
    f = model.eval(wi, wo, ShadingPoint(uv=uv, lod=lod, u_level=u))
    assert f.shape == (n, 3) and torch.isfinite(f).all() and (f >= 0).all()
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert (f[below] == 0).all()
    wi.requires_grad_(True)
    model.eval(wi, wo, uv).sum().backward()
    assert all(torch.isfinite(lv.grad).all() for lv in model.maps.levels if lv.grad is not None)


def test_usd_preview_surface_opens_and_references_the_baked_textures(tmp_path):
    import OpenImageIO as oiio
    from pxr import Usd, UsdShade

    model = AnalyticMaterial((4, 8))
    with torch.no_grad():
        model.maps.levels[0].normal_(0, 1, generator=torch.Generator().manual_seed(2))
    assert len(CHANNELS) == 8
    baked = write_preview_textures(model, tmp_path / "preview")
    stage = Usd.Stage.CreateNew(str(tmp_path / "preview" / "analytic.usda"))
    UsdShade.Material.Define(stage, "/Looks/Analytic")
    author_preview_surface(stage, "/Looks/Analytic", {k: f"./{p.name}" for k, p in baked["textures"].items()},
                           baked["ior"])
    stage.GetRootLayer().Save()
    stage = Usd.Stage.Open(str(tmp_path / "preview" / "analytic.usda"))
    mat = UsdShade.Material(stage.GetPrimAtPath("/Looks/Analytic"))
    surf = mat.ComputeSurfaceSource()[0]
    assert surf.GetIdAttr().Get() == "UsdPreviewSurface"
    for name in ("diffuseColor", "roughness", "metallic", "normal"):
        src = surf.GetInput(name).GetConnectedSources()[0][0].source
        tex = UsdShade.Shader(src.GetPrim())
        asset = tex.GetInput("file").Get()
        resolved = (tmp_path / "preview" / asset.path).resolve()
        assert resolved.is_file() and resolved == baked["textures"][name].resolve()
        spec = oiio.ImageInput.open(str(resolved)).spec()
        assert (spec.width, spec.height) == (8, 4)
    normal = oiio.ImageInput.open(str(baked["textures"]["normal"])).read_image("float")
    n = np.asarray(normal) * 2 - 1
    assert np.allclose(np.linalg.norm(n, axis=-1), 1, atol=2e-3) and (n[..., 2] > 0).all()
    assert 1.0 < baked["ior"] < 3.0


def test_cosine_lr_follows_torchs_cosine_annealing():
    """The fit's schedule (:func:`~mtlx2neural.train.adam.cosine_lr`, closed form) gives the learning rates of
    ``torch.optim.lr_scheduler.CosineAnnealingLR`` (``eta_min`` lr/10), which the fit used before it took the
    project's own Adam; 1e-12 relative: the scheduler's recursive update rounds differently."""
    from mtlx2neural.train.adam import cosine_lr

    steps, lr = 37, 3e-2
    opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=lr / 10)
    for step in range(steps + 1):
        assert cosine_lr(lr, lr / 10, step, steps) == pytest.approx(opt.param_groups[0]["lr"], rel=1e-12)
        opt.step()
        sched.step()
