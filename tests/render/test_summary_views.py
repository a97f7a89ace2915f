"""The views behind a material's summary figure (``render.summary_views``): three directional views, one
of them showing the light's mirror highlight, and one under the sky, where a lost coat reflection shows."""

from __future__ import annotations

import torch
from closure_docs import closure_material
from materials import reference_of, standard_surface

from mtlx2neural.render.geometry import OrthographicCamera
from mtlx2neural.render.renderer import VIEWS
from mtlx2neural.render.summary_views import describe, summary_views, views_per_tile


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
