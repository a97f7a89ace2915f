"""Emission and opacity maps (mtlx2neural.textures.surface_maps): coverage-preserving MIPs, coverage-
weighted emission, dilation, lookups, and maps built from a real MaterialX cut-out."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint, coverage_of
from mtlx2neural.textures.surface_maps import (
    ALPHA_CUTOFF,
    SurfaceMaps,
    build_surface_maps,
    coverage_preserving,
    dilate,
    level_shapes,
)


def _fern(res: int = 64, seed: int = 0) -> torch.Tensor:
    """[1, res, res] binary mask of thin wavy strands (about a texel wide): foliage, where a plain
    box-filtered MIP chain tested at 0.5 loses the strands at the first coarser level."""
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.arange(res, dtype=torch.float32), torch.arange(res, dtype=torch.float32),
                          indexing="ij")
    mask = torch.zeros(res, res)
    for _ in range(7):
        base, amp, freq, phase = (torch.rand(4, generator=g) * torch.tensor([res, 6.0, 3.0, 6.28])).tolist()
        centre = base + amp * torch.sin(2 * torch.pi * freq * x / res + phase)
        mask[(torch.remainder(y - centre + res / 2, res) - res / 2).abs() < 0.6] = 1.0
    return mask[None]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coverage_preserving_mips_keep_a_ferns_coverage(seed):
    """Share of texels passing the 0.5 test at every level within 15 % of level 0's plus 1.5 texels
    (texels with equal values pass together: measured at most 10 % off on these seeds); the plain box
    chain drops below half of it, so the test can fail."""
    mask = _fern(seed=seed)
    target = float((mask >= ALPHA_CUTOFF).float().mean())
    levels = coverage_preserving(mask, len(level_shapes(64, 64)))
    assert [tuple(lv.shape[1:]) for lv in levels] == level_shapes(64, 64)
    plain = mask
    for k, lv in enumerate(levels[1:-2], start=1):  # the 2x2 and 1x1 levels cannot hold a share finely
        got = float((lv >= ALPHA_CUTOFF).float().mean())
        assert abs(got - target) <= 1.5 / lv[0].numel() + 0.15 * target, (k, got, target)
        plain = torch.nn.functional.avg_pool2d(plain[None], 2, ceil_mode=True)[0]
    assert float((plain >= ALPHA_CUTOFF).float().mean()) < 0.5 * target  # what the box chain alone does


def test_emission_of_a_cut_out_is_averaged_over_the_surface_that_is_there():
    """An emitter whose empty texels hold a garbage value: coarser levels show the emitter's own colour."""
    cover = torch.zeros(1, 8, 8)
    cover[:, :, :3] = 1.0
    e0 = torch.where(cover.bool(), torch.tensor([2.0, 1.0, 0.5])[:, None, None], torch.tensor(100.0))
    levels, weighted, weight = [e0], e0 * cover, cover
    from mtlx2neural.textures.surface_maps import _pool  # the module's own 2x2 mean

    for _ in range(3):
        weighted, weight, plain = _pool(weighted), _pool(weight), _pool(levels[-1])
        levels.append(torch.where(weight > 1e-6, weighted / weight.clamp_min(1e-6), plain))
    torch.testing.assert_close(levels[-1][:, 0, 0], torch.tensor([2.0, 1.0, 0.5]))


def test_dilate_fills_empty_texels_from_their_neighbours_and_keeps_the_rest():
    grid = torch.zeros(2, 6, 6)
    covered = torch.zeros(6, 6, dtype=torch.bool)
    covered[2:4, 2:4] = True
    grid[:, 2:4, 2:4] = torch.tensor([3.0, -1.0])[:, None, None]
    grid[:, ~covered] = 50.0  # untrained values
    out = dilate(grid, covered)
    torch.testing.assert_close(out, torch.tensor([3.0, -1.0])[:, None, None].expand(2, 6, 6).contiguous())
    assert torch.equal(dilate(grid, torch.ones(6, 6, dtype=torch.bool)), grid)


def test_lookups_read_the_level_the_lod_asks_for():
    e = [torch.full((3, 4, 4), 1.0), torch.full((3, 2, 2), 2.0), torch.full((3, 1, 1), 3.0)]
    o = [torch.ones(1, 4, 4), torch.zeros(1, 2, 2), torch.zeros(1, 1, 1)]
    maps = SurfaceMaps(emission_levels=e, opacity_levels=o, alpha_mode="mask")
    uv = torch.rand(5, 2)
    for lod, want in ((0.0, 1.0), (1.0, 2.0), (7.0, 3.0)):
        at = ShadingPoint(uv=uv, lod=torch.full((5,), lod), u_level=torch.zeros(5))
        torch.testing.assert_close(maps.emission(at), torch.full((5, 3), want))
    # lod 0.5: level 1 where u_level < 0.5, level 0 elsewhere; a mask's coverage is alpha-tested
    at = ShadingPoint(uv=uv, lod=torch.full((5,), 0.5), u_level=torch.tensor([0.1, 0.9, 0.2, 0.8, 0.4]))
    torch.testing.assert_close(coverage_of(maps, at), torch.tensor([0.0, 1.0, 0.0, 1.0, 0.0]))


def test_maps_of_a_gltf_mask_material(tmp_path):
    """glTF alpha_mode MASK with an alpha texture: a mask whose level-0 coverage is the texture's share
    above the cutoff, and no emission."""
    import OpenImageIO as oiio

    alpha = np.zeros((16, 16, 1), np.float32)
    alpha[:, :5] = 0.8  # 5 of 16 columns above the 0.5 cutoff
    alpha[:, 5:7] = 0.3
    path = tmp_path / "alpha.exr"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(16, 16, 1, "float"))
    out.write_image(alpha)
    out.close()
    (tmp_path / "m.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n'
        '  <image name="a" type="float"><input name="file" type="filename" value="alpha.exr"/>'
        '<input name="filtertype" type="string" value="closest"/></image>\n'
        '  <gltf_pbr name="sh" type="surfaceshader"><input name="alpha" type="float" nodename="a"/>'
        '<input name="alpha_mode" type="integer" value="1"/></gltf_pbr>\n'
        '  <surfacematerial name="M" type="material"><input name="surfaceshader" type="surfaceshader" '
        'nodename="sh"/></surfacematerial>\n</materialx>\n')
    ref = m2n.load_reference(tmp_path / "m.mtlx")
    maps = build_surface_maps(ref.compiled, (16, 16))
    assert maps.alpha_mode == "mask" and not maps.emits
    assert maps.coverage == pytest.approx(5 / 16)
    assert len(maps.opacity_levels) == len(level_shapes(16, 16))
    assert maps.describe()["opacity"] == "texture"
