"""Texture input (mtlx2neural.imaging.image_io / udim / texel_lookup).

Every test writes real files with OpenImageIO into tmp_path (seeded data) and
reads them back through the module. Tolerances are the file format's own
quantisation: 8-bit round-trips to within half a step (0.5/255), 16-bit to
0.5/65535, half EXR to half precision (relative 2^-11, and bit-exact against
numpy's float16 rounding), float EXR exactly.
"""

from __future__ import annotations

import os
import time

import numpy as np
import OpenImageIO as oiio
import pytest
import torch
from conftest import shared_path
from hypothesis import given, settings
from hypothesis import strategies as st

from mtlx2neural.errors import InputError
from mtlx2neural.imaging.image_io import (
    Texture,
    TextureCache,
    mip_level_count,
    read_image,
    texture_cache,
)
from mtlx2neural.imaging.udim import discover_tiles, tile_path, udim_number

QUANT_8 = 0.5 / 255 + 1e-6
QUANT_16 = 0.5 / 65535 + 1e-7
ADDRESS = ("periodic", "clamp", "mirror", "constant")


def _rand(shape, seed=0):
    return np.random.default_rng(seed).random(shape).astype(np.float32)


def _write(path, pixels, fmt="float", colorspace=None, tiles=None):
    """Write ``pixels`` [H, W, C] float32 (row 0 = top) as ``fmt`` with OpenImageIO."""
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.attribute("oiio:UnassociatedAlpha", 1)  # the arrays hold straight alpha: store them as they are
    if colorspace:
        spec.attribute("oiio:ColorSpace", colorspace)
    if tiles:
        spec.tile_width = spec.tile_height = tiles
    out = oiio.ImageOutput.create(str(path))
    assert out is not None, oiio.geterror()
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, dtype=np.float32)), out.geterror()
    out.close()
    return str(path)


def _uv(*pts):
    return torch.tensor(pts, dtype=torch.float32)


# --------------------------------------------------------------------------- reading


@pytest.mark.parametrize("ext,fmt,tol", [
    ("png", "uint8", QUANT_8),
    ("tif", "uint8", QUANT_8),
    ("png", "uint16", QUANT_16),
    ("tif", "uint16", QUANT_16),
    ("tif", "float", 0.0),
    ("exr", "float", 0.0),
])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_round_trip_integer_and_float(tmp_path, ext, fmt, tol, channels):
    a = _rand((7, 11, channels), seed=channels)
    path = _write(tmp_path / f"img_{fmt}_{channels}.{ext}", a, fmt)
    d = read_image(path)
    assert d.pixels.dtype == np.float32 and d.pixels.shape == (7, 11, channels)
    assert d.file_format == fmt
    assert np.abs(d.pixels - a).max() <= tol
    assert d.tensor().shape == (7, 11, channels)


def test_round_trip_half_exr(tmp_path):
    a = (_rand((9, 5, 4), seed=3) * 8 - 2).astype(np.float32)  # values in [-2, 6): HDR and negative
    d = read_image(_write(tmp_path / "half.exr", a, "half"))
    assert d.file_format == "half"
    np.testing.assert_array_equal(d.pixels, a.astype(np.float16).astype(np.float32))
    assert np.all(np.abs(d.pixels - a) <= np.abs(a) * 2.0 ** -11 + 2.0 ** -24)


def test_round_trip_jpeg_smooth(tmp_path):
    # JPEG is lossy; a smooth gradient at quality 100 without chroma subsampling stays within 3/255.
    y, x = np.mgrid[0:16, 0:24].astype(np.float32)
    a = np.stack([x / 23, y / 15, 0.5 + 0 * x], -1).astype(np.float32)
    spec = oiio.ImageSpec(24, 16, 3, "uint8")
    spec.attribute("Compression", "jpeg:100")
    spec.attribute("jpeg:subsampling", "4:4:4")
    path = str(tmp_path / "smooth.jpg")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, spec) and out.write_image(a), out.geterror()
    out.close()
    d = read_image(path)
    assert d.pixels.shape == (16, 24, 3) and d.file_format == "uint8"
    assert np.abs(d.pixels - a).max() <= 3 / 255


def test_png_alpha_stays_straight(tmp_path):
    # a half-transparent red texel reads back as (1, 0, 0, 0.5), not premultiplied
    a = np.array([[[1.0, 0.0, 0.0, 0.5], [0.2, 0.4, 0.6, 0.0]]], dtype=np.float32)
    d = read_image(_write(tmp_path / "alpha.png", a, "uint8"))
    assert np.abs(d.pixels - a).max() <= QUANT_8


def test_colour_space_metadata(tmp_path):
    d = read_image(_write(tmp_path / "acescg.exr", _rand((2, 2, 3)), "half", colorspace="ACEScg"))
    # OpenImageIO 3 canonicalises colour space names (ACEScg -> lin_ap1_scene).
    assert d.colorspace in ("ACEScg", "lin_ap1_scene")
    assert read_image(_write(tmp_path / "plain.tif", _rand((2, 2, 3)), "float")).colorspace is None
    png = read_image(_write(tmp_path / "c.png", _rand((2, 2, 3)), "uint8"))
    assert png.colorspace is not None and "srgb" in png.colorspace.lower()
    assert Texture(tmp_path / "acescg.exr").colorspace == d.colorspace


def test_tx_mip_levels(tmp_path):
    src = _rand((16, 32, 4), seed=7)
    cfg = oiio.ImageSpec()
    cfg.attribute("maketx:filtername", "box")
    cfg.tile_width = cfg.tile_height = 16
    path = str(tmp_path / "tex.tx")
    assert oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, oiio.ImageBuf(src), path, cfg), oiio.geterror()

    assert mip_level_count(path) == 6  # 32x16, 16x8, 8x4, 4x2, 2x1, 1x1
    l0 = read_image(path)
    assert l0.miplevel == 0 and l0.mip_levels == 6
    np.testing.assert_array_equal(l0.pixels, src)
    l1 = read_image(path, miplevel=1)
    assert l1.pixels.shape == (8, 16, 4)
    box = src.reshape(8, 2, 16, 2, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(l1.pixels, box, atol=1e-6)
    assert read_image(path, miplevel=5).pixels.shape == (1, 1, 4)
    with pytest.raises(InputError, match="6 MIP level"):
        read_image(path, miplevel=6)
    # sampling a chosen level: the centre of level-1 texel (0, 0) returns it exactly
    t1 = Texture(path, miplevel=1)
    got = t1.sample(_uv([0.5 / 16, 1 - 0.5 / 8]), filtertype="linear")
    np.testing.assert_allclose(got.numpy()[0], box[0, 0], atol=1e-6)


# --------------------------------------------------------------------------- errors


def test_missing_file_names_path_and_node(tmp_path):
    missing = tmp_path / "nope.png"
    with pytest.raises(InputError, match="nope.png") as e:
        read_image(missing)
    assert "does not exist" in str(e.value)
    with pytest.raises(InputError, match="nope.png.*node '/NG/image1'"):
        Texture(missing, node="/NG/image1")


def test_unreadable_file_reports_oiio_message(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"this is not a png at all" * 10)
    with pytest.raises(InputError, match="cannot read texture file .*bad.png") as e:
        read_image(bad, node="img")
    assert len(str(e.value).split(":", 1)[1].strip()) > 0  # OIIO's own message follows


def test_missing_udim_set(tmp_path):
    with pytest.raises(InputError, match=r"col\.<UDIM>\.png.*node 'n1'"):
        Texture(tmp_path / "col.<UDIM>.png", node="n1")


# --------------------------------------------------------------------------- sampling


@pytest.fixture
def quad(tmp_path):
    """2x2 RGB float EXR; texel values by position (row 0 = top)."""
    a = np.array([[[1, 0, 0], [0, 1, 0]],      # top-left red, top-right green
                  [[0, 0, 1], [1, 1, 0]]],     # bottom-left blue, bottom-right yellow
                 dtype=np.float32)
    return a, Texture(_write(tmp_path / "quad.exr", a))


def test_uv_origin_is_bottom_left(quad):
    a, tex = quad
    got = tex.sample(_uv([0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]), filtertype="closest")
    np.testing.assert_array_equal(got.numpy(), [a[1, 0], a[1, 1], a[0, 0], a[0, 1]])


def test_linear_halfway_between_texel_centres_averages(quad):
    a, tex = quad
    got = tex.sample(_uv([0.5, 0.25], [0.25, 0.5], [0.5, 0.5]), filtertype="linear").numpy()
    np.testing.assert_allclose(got[0], (a[1, 0] + a[1, 1]) / 2, atol=1e-6)
    np.testing.assert_allclose(got[1], (a[0, 0] + a[1, 0]) / 2, atol=1e-6)
    np.testing.assert_allclose(got[2], a.mean(axis=(0, 1)), atol=1e-6)
    # at a texel centre, linear returns the texel itself
    np.testing.assert_allclose(tex.sample(_uv([0.75, 0.75])).numpy()[0], a[0, 1], atol=1e-6)


def test_address_modes_outside_unit_square(tmp_path):
    row = np.arange(4, dtype=np.float32).reshape(1, 4, 1)  # texels 0 1 2 3 along u
    tex = Texture(_write(tmp_path / "row.exr", row))
    # u in texel units: -0.5 -> texel -1, -1.5 -> -2, 4.5 -> 4, 5.5 -> 5, 9.5 -> 9
    us = [-0.5 / 4, -1.5 / 4, 4.5 / 4, 5.5 / 4, 9.5 / 4]
    expect = {
        "periodic": [3, 2, 0, 1, 1],
        "clamp": [0, 0, 3, 3, 3],
        "mirror": [0, 1, 3, 2, 1],      # ... 1 0 | 0 1 2 3 | 3 2 1 0 | 0 1 ...
        "constant": [-7, -7, -7, -7, -7],
    }
    uv = torch.tensor([[u, 0.5] for u in us])
    for mode, want in expect.items():
        got = tex.sample(uv, uaddress=mode, vaddress="clamp", filtertype="closest",
                         default=torch.tensor([-7.0]))
        np.testing.assert_array_equal(got[:, 0].numpy(), want, err_msg=mode)
    # v behaves the same way: periodic v=1.25 is v=0.25; constant v=-0.01 is the default
    quad = np.array([[[5.0], [6.0]], [[7.0], [8.0]]], dtype=np.float32)
    t2 = Texture(_write(tmp_path / "q1.exr", quad))
    got = t2.sample(_uv([0.25, 1.25], [0.25, -0.01]), vaddress="periodic", filtertype="closest")
    assert got[0, 0] == 7.0
    got = t2.sample(_uv([0.25, -0.01], [0.25, 0.01]), vaddress="constant", filtertype="closest",
                    default=torch.tensor([9.0]))
    assert got[0, 0] == 9.0 and got[1, 0] == 7.0


def test_constant_border_blends_default_inside(tmp_path):
    # inside [0,1], a linear tap beyond the edge reads the default (GPU CLAMP_TO_BORDER)
    row = np.full((1, 2, 1), 4.0, dtype=np.float32)
    tex = Texture(_write(tmp_path / "b.exr", row))
    got = tex.sample(_uv([0.0, 0.5]), uaddress="constant", vaddress="clamp", default=torch.tensor([2.0]))
    assert got.item() == pytest.approx(3.0)


@pytest.mark.parametrize("filtertype,interp", [
    ("closest", oiio.InterpMode.Closest),
    ("linear", oiio.InterpMode.Bilinear),
    ("cubic", oiio.InterpMode.Bicubic),
])
@pytest.mark.parametrize("mode,wrap", [
    ("periodic", oiio.Wrap.Periodic), ("clamp", oiio.Wrap.Clamp),
    ("mirror", oiio.Wrap.Mirror), ("constant", oiio.Wrap.Black)])
def test_matches_oiio_texture_system(tmp_path, filtertype, interp, mode, wrap):
    """Oracle: OpenImageIO's TextureSystem (what MaterialX's OSL image node calls) at MIP level 0.

    OIIO's t axis points down, so t = 1 - v. For ``constant`` OIIO's black wrap
    agrees inside [0, 1]; outside it MaterialX returns the default (0 here).
    """
    a = _rand((5, 7, 3), seed=11)
    path = _write(tmp_path / "oracle.exr", a)
    uv = np.random.default_rng(12).uniform(-1.5, 2.5, (200, 2))
    opt = oiio.TextureOpt()
    opt.interpmode, opt.swrap, opt.twrap = interp, wrap, wrap
    ts = oiio.TextureSystem(False)
    try:
        ref = np.array([ts.texture(path, opt, float(u), float(1 - v), 0, 0, 0, 0, 3) for u, v in uv])
    finally:
        oiio.TextureSystem.destroy(ts)
    got = Texture(path).sample(torch.tensor(uv, dtype=torch.float32), uaddress=mode, vaddress=mode,
                               filtertype=filtertype).numpy()
    if mode == "constant":
        inside = ((uv >= 0) & (uv <= 1)).all(1)
        np.testing.assert_array_equal(got[~inside], 0.0)
        got, ref = got[inside], ref[inside]
    np.testing.assert_allclose(got, ref, atol=2e-6)


def test_cubic_is_bspline(tmp_path):
    # a single bright texel on a dark row: the B-spline spreads 1/6, 4/6, 1/6 at texel centres
    row = np.zeros((1, 8, 1), dtype=np.float32)
    row[0, 4, 0] = 6.0
    tex = Texture(_write(tmp_path / "spike.exr", row))
    uv = torch.tensor([[(i + 0.5) / 8, 0.5] for i in range(8)])
    got = tex.sample(uv, filtertype="cubic")[:, 0].numpy()
    np.testing.assert_allclose(got, [0, 0, 0, 1, 4, 1, 0, 0], atol=1e-5)


def test_default_and_channels(tmp_path):
    tex = Texture(_write(tmp_path / "g.exr", _rand((4, 4, 1))))
    assert tex.channels == 1
    per_row = torch.tensor([[1.0], [2.0]])
    got = tex.sample(_uv([2.0, 0.5], [-1.0, 0.5]), uaddress="constant", default=per_row)
    np.testing.assert_array_equal(got.numpy(), [[1.0], [2.0]])
    with pytest.raises(ValueError, match="channels"):
        tex.sample(_uv([0.5, 0.5]), default=torch.zeros(3))
    with pytest.raises(ValueError, match="filtertype"):
        tex.sample(_uv([0.5, 0.5]), filtertype="bilinear")
    with pytest.raises(ValueError, match="uaddress"):
        tex.sample(_uv([0.5, 0.5]), uaddress="repeat")
    assert tex.sample(torch.zeros(0, 2)).shape == (0, 1)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(u=st.floats(allow_nan=True, allow_infinity=True, width=32),
       v=st.floats(allow_nan=True, allow_infinity=True, width=32),
       mode=st.sampled_from(ADDRESS), filtertype=st.sampled_from(("closest", "linear", "cubic")))
def test_sample_is_finite_and_bounded(u, v, mode, filtertype):
    """Any uv, NaN and Inf included: finite output within the texel range (all filters are convex)."""
    a = _rand((3, 5, 2), seed=5)
    tex = Texture.from_array(a)
    got = tex.sample(torch.tensor([[u, v]], dtype=torch.float32), uaddress=mode, vaddress=mode,
                     filtertype=filtertype, default=torch.tensor([0.5, 0.5]))
    assert torch.isfinite(got).all()
    assert got.min() >= min(a.min(), 0.5) - 1e-6 and got.max() <= max(a.max(), 0.5) + 1e-6


# --------------------------------------------------------------------------- cache


def test_cache_hits_reloads_and_evicts(tmp_path):
    cache = TextureCache(budget_bytes=3 * 16 * 16 * 4 * 4)  # room for three 16x16x4 float images
    paths = [_write(tmp_path / f"c{i}.exr", _rand((16, 16, 4), seed=i)) for i in range(4)]
    first = read_image(paths[0], cache=cache)
    assert read_image(paths[0], cache=cache) is first and cache.hits == 1
    for p in paths[1:]:
        read_image(p, cache=cache)
    assert len(cache) == 3 and cache.nbytes <= cache.budget_bytes
    assert read_image(paths[0], cache=cache) is not first  # least recently used, evicted
    # rewriting a file (new mtime) invalidates its entry
    new = np.full((16, 16, 4), 0.25, dtype=np.float32)
    time.sleep(0.01)
    _write(paths[0], new)
    os.utime(paths[0], ns=(time.time_ns(), time.time_ns() + 10_000_000))
    np.testing.assert_array_equal(read_image(paths[0], cache=cache).pixels, new)
    assert sum(1 for k in cache._items if k[0] == os.path.realpath(paths[0])) == 1
    cache.set_budget(0)
    assert len(cache) == 0 and cache.nbytes == 0
    assert texture_cache().budget_bytes == 2 << 30


# --------------------------------------------------------------------------- UDIM


COLOURS = {1001: (1.0, 0.0, 0.0), 1002: (0.0, 1.0, 0.0), 1011: (0.0, 0.0, 1.0), 1012: (1.0, 1.0, 0.0)}


def _udim_set(tmp_path, tiles=(1001, 1002, 1011), token="<UDIM>", size=4):
    """A set of constant-colour 8-bit PNG tiles; returns the pattern."""
    pattern = str(tmp_path / f"col.{token}.png")
    for udim in tiles:
        k = udim - 1001
        img = np.broadcast_to(np.array(COLOURS[udim], dtype=np.float32), (size, size, 3))
        _write(tile_path(pattern, k % 10, k // 10), img, "uint8")
    return pattern


def test_udim_tiles_by_uv(tmp_path):
    tex = Texture(_udim_set(tmp_path), node="img")
    assert tex.is_udim and sorted(tex.tiles) == [1001, 1002, 1011]
    assert (tex.range.u0, tex.range.v0, tex.range.u1, tex.range.v1) == (0, 0, 2, 2)
    default = torch.tensor([0.5, 0.25, 0.125])
    got = tex.sample(_uv([0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5]), default=default).numpy()
    np.testing.assert_allclose(got[:3], [COLOURS[1001], COLOURS[1002], COLOURS[1011]], atol=QUANT_8)
    np.testing.assert_array_equal(got[3], default.numpy())  # tile 1012 is missing
    assert torch.equal(tex.sample(_uv([1.5, 1.5])), torch.zeros(1, 3))  # no default: 0


def test_udim_address_modes_over_tile_range(tmp_path):
    tex = Texture(_udim_set(tmp_path))   # range [0,2] x [0,2]
    uv = _uv([5.5, 0.5], [-0.5, 0.5], [2.5, 0.5], [3.5, 0.5], [-3.25, 0.5], [7.25, 0.5])
    d = torch.tensor([0.5, 0.5, 0.5])
    red, green = COLOURS[1001], COLOURS[1002]
    want = {
        "periodic": [green, green, red, green, red, green],
        "mirror": [green, red, green, red, red, red],
        "clamp": [green, red, green, green, red, green],
        "constant": [d.tolist()] * 6,
    }
    for mode, w in want.items():
        got = tex.sample(uv, uaddress=mode, vaddress="clamp", default=d).numpy()
        np.testing.assert_allclose(got, w, atol=QUANT_8, err_msg=mode)


def test_uvtile_token_and_udimset(tmp_path):
    pattern = _udim_set(tmp_path, tiles=(1001, 1002, 1012), token="<UVTILE>")
    assert os.path.exists(tmp_path / "col.u2_v2.png")  # 1-based: tile 1012 is u2_v2
    found = discover_tiles(pattern)
    assert sorted(udim_number(*t) for t in found) == [1001, 1002, 1012]
    tex = Texture(pattern)
    got = tex.sample(_uv([1.5, 1.5], [0.5, 0.5])).numpy()
    np.testing.assert_allclose(got, [COLOURS[1012], COLOURS[1001]], atol=QUANT_8)
    # a declared udimset restricts the set (and may name tiles that are missing)
    only = Texture(pattern, udimset=[1001, 1011])
    assert only.tiles[1011] is None and sorted(only.tiles) == [1001, 1011]
    with pytest.raises(InputError, match="no tile"):
        Texture(pattern, udimset=[1021])


def test_single_tile_udim_samples_like_the_image(tmp_path):
    a = _rand((4, 6, 3), seed=9)
    _write(tmp_path / "one.1001.exr", a)
    uv = torch.tensor(np.random.default_rng(1).uniform(-1, 2, (64, 2)), dtype=torch.float32)
    for mode in ADDRESS:
        for ft in ("closest", "linear", "cubic"):
            u = Texture(tmp_path / "one.<UDIM>.exr").sample(uv, uaddress=mode, vaddress=mode, filtertype=ft)
            p = Texture(tmp_path / "one.1001.exr").sample(uv, uaddress=mode, vaddress=mode, filtertype=ft)
            torch.testing.assert_close(u, p, atol=1e-6, rtol=0)


def test_real_grid_udim_set():
    folder = shared_path("materialx", "resources", "Images", "grid_udim")
    tex = Texture(os.path.join(folder, "grid.<UDIM>.png"))
    assert sorted(tex.tiles) == [1001, 1002, 1003, 1011, 1012, 1013]
    assert all(os.path.basename(p) == f"grid.{n}.png" for n, p in tex.tiles.items())
    assert tex.channels == 3 and tex.colorspace is not None
    centres, expect = [], []
    for n, p in tex.tiles.items():
        tu, tv = (n - 1001) % 10, (n - 1001) // 10
        centres.append([tu + 0.5, tv + 0.5])
        buf = oiio.ImageBuf(p)  # read independently of the module
        w, h = buf.spec().width, buf.spec().height
        expect.append(buf.getpixel(w // 2, h // 2))  # texel containing the tile's centre
    got = tex.sample(torch.tensor(centres), filtertype="closest").numpy()
    np.testing.assert_allclose(got, np.array(expect), atol=1e-6)
    # the six tiles really are different images, so a wrong tile would be caught
    assert len({tuple(np.round(e, 4)) for e in expect}) > 1
