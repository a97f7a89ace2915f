"""The views behind a material's summary figure (``render.summary_views``): three directional views, one
of them showing the light's mirror highlight, and one under the sky, where a lost coat reflection shows."""

from __future__ import annotations

import torch
from closure_docs import closure_material
from materials import reference_of, standard_surface

from mtlx2neural.model import proxy
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.geometry import OrthographicCamera
from mtlx2neural.render.renderer import VIEWS
from mtlx2neural.render.summary_views import (
    describe,
    describe_viewer,
    summary_views,
    viewer_view,
    views_per_tile,
)


def test_the_first_directional_view_shows_the_lights_mirror_highlight():
    view = VIEWS[0]
    d, right, up = OrthographicCamera(view.azimuth, view.elevation).basis()
    light = torch.nn.functional.normalize(torch.tensor(view.light, dtype=torch.float32), dim=0)
    h = torch.nn.functional.normalize(d + light, dim=0)  # the sphere's normal where the mirror highlight is
    # well inside the visible disc (cosine to the camera > 0.5, not at the limb), so inside the image
    assert float(h @ d) > 0.5
    assert abs(float(h @ right)) < 1.0 and abs(float(h @ up)) < 1.0


def test_rows_follow_the_description_and_a_faithful_model_scores_zero():
    diffuse = closure_material("oren_nayar_diffuse_bsdf", color=(0.5, 0.3, 0.2))
    rows = summary_views(diffuse, {"same": diffuse}, (1, 1))["same"]
    assert [r["lighting"] for r in rows] == ["directional"] * len(VIEWS) + ["environment"]
    assert len(rows) == views_per_tile() == len(describe()) and describe()[-1].startswith("environment")
    # common random numbers: the same material renders the same image, so every view's FLIP is 0
    assert all(r["flip"] == 0.0 for r in rows)


def test_a_lost_coat_reflection_shows_in_the_environment_view():
    coat = reference_of(standard_surface("M", "SR", base_color=(0.5, 0.05, 0.04), specular=0.0, coat=1.0,
                                         coat_roughness=0.02))
    bare = reference_of(standard_surface("M", "SR", base_color=(0.5, 0.05, 0.04), specular=0.0))
    rows = summary_views(coat, {"bare": bare}, (1, 1))["bare"]
    lit = [r["flip"] for r in rows if r["lighting"] == "directional"]
    (sky,) = [r["flip"] for r in rows if r["lighting"] == "environment"]
    # measured 0.09 / 0.07 / 0.09 under the lights and 0.37 under the sky: the sky view sees the missing
    # reflection at least twice as clearly as any directional view (margin for the estimates' noise)
    assert sky > 2 * max(lit)


class LambertianWithLobes:
    """A Lambertian reference (MaterialX's ``oren_nayar_diffuse_bsdf``, roughness 0) that also answers
    :meth:`environment_lobes` as a model with an environment head does: all its reflectance, ``scale`` x
    its albedo, in a cosine lobe about the normal, which the prefiltered path shades with the sky's
    irradiance / pi: the exact answer for a Lambertian at ``scale`` 1, up to the irradiance's order-2
    harmonics."""

    has_environment_head = True

    def __init__(self, color, scale: float = 1.0):
        self.ref = closure_material("oren_nayar_diffuse_bsdf", color=color, roughness=0.0)
        self.color, self.scale = torch.tensor(color), scale

    def __getattr__(self, name):  # eval, sample, pdf...: the reference's
        return getattr(self.ref, name)

    def environment_lobes(self, wi, at=None):
        n = wi.shape[0]
        params = proxy.ProxyParams(torch.full((n, 2), 0.5), torch.zeros(n, 1), torch.zeros(n, 2), torch.zeros(n, 2),
                                   torch.zeros(n, 1))
        c = torch.stack([torch.zeros(n, 3), torch.zeros(n, 3), (self.scale * self.color).expand(n, 3)], 1)
        return wi, params, torch.where(wi[:, None, 2:3] > 0, c, torch.zeros_like(c))


def test_the_viewer_view_sees_the_prefiltered_paths_error_not_the_brdfs():
    """The viewer figure compares the prefiltered path with the reference: a Lambertian shaded from its
    exact lobe reflectance matches it; the same BRDF with its lobe reflectance 30 % low (a prefiltered
    path gone wrong) does not, while the environment view, which samples the BRDF, cannot tell them apart."""
    color = (0.6, 0.4, 0.2)
    right, wrong = LambertianWithLobes(color), LambertianWithLobes(color, scale=0.7)
    rows = summary_views(right.ref, {"right": right, "wrong": wrong}, (1, 1), res=48, spp=8)
    assert rows["right"][-1]["flip"] == rows["wrong"][-1]["flip"] == 0.0  # same BRDF, same random numbers
    good = viewer_view(right.ref, right, (1, 1), res=48)
    bad = viewer_view(right.ref, wrong, (1, 1), res=48)
    # measured 0.042 (the 128-pass reference's noise and the limb's coverage) against 0.25: the 30 %
    # darker sphere must read at least 3x the faithful one, which stays under the samples' figures
    # under the sky (0.05-0.10)
    assert good["flip"] < 0.06, good["flip"]
    assert bad["flip"] > 3 * good["flip"], (good["flip"], bad["flip"])
    assert good["image"].shape == good["reference"].shape == (48, 48, 3)
    assert describe_viewer().startswith("viewer: the environment view")


def test_a_model_without_an_environment_head_has_no_viewer_view():
    torch.manual_seed(0)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16")
    assert viewer_view(model, model, (4, 4)) is None
