"""Evaluation renderer and image errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

import mtlx2neural as m2n
from mtlx2neural.evaluate.render import VIEWS, _lod, image_errors, reference_fn, render

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "layered_spheres.usda"


def test_sphere_render_and_flip():
    ref = m2n.load_reference(SAMPLE, "/World/Looks/Plastic")
    img = render(reference_fn(ref), VIEWS[0], res=48, spp=2)
    assert img.shape == (48, 48, 3) and np.isfinite(img).all()
    assert img[0, 0].sum() == 0 and img[24, 24].sum() > 0  # background corner vs lit centre
    same = image_errors(img, img)
    assert same["flip"] == 0.0 and same["mae"] == 0.0
    dark = image_errors(img, img * 0.5)
    assert dark["flip"] > 0.05 and dark["relmse"] > 0.0  # halving the brightness is clearly visible


def test_lod_grows_with_texture_resolution():
    uv = torch.rand(32 * 32, 2)
    uv = torch.stack(torch.meshgrid(torch.linspace(0, 0.5, 32), torch.linspace(0, 0.5, 32), indexing="xy"), -1)
    uv = uv.reshape(-1, 2)
    # One pixel spans 0.5/31 of UV: ~16 texels of a 1024 texture (lod ~4), less than one of a 16 texture.
    assert abs(float(_lod(uv, 32, (1024, 1024)).median()) - np.log2(1024 * 0.5 / 31)) < 0.1
    assert float(_lod(uv, 32, (16, 16)).max()) == 0.0
