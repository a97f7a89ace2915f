"""Texture colour conversion (mtlx2neural.imaging.colour)."""

import numpy as np
import PyOpenColorIO as OCIO
import pytest
import torch

from mtlx2neural.errors import InputError
from mtlx2neural.imaging import colour

MATERIALX_SPACES = ["srgb_texture", "lin_rec709", "acescg", "lin_ap1", "g22_rec709", "g18_rec709",
                    "g22_ap1", "g18_ap1", "adobergb", "lin_adobergb", "srgb_displayp3", "lin_displayp3",
                    "rec709_display", "lin_srgb", "raw"]


@pytest.fixture(autouse=True)
def _builtin_config(monkeypatch):
    """Every test starts on the built-in config unless it sets $OCIO itself."""
    monkeypatch.delenv("OCIO", raising=False)
    yield


def _xy_to_xyz(x, y):
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def _rgb_to_xyz(primaries, white):
    p = np.stack([_xy_to_xyz(*c) for c in primaries], axis=1)
    return p * np.linalg.solve(p, _xy_to_xyz(*white))


def _bradford(src_white, dst_white):
    b = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
    s, d = b @ _xy_to_xyz(*src_white), b @ _xy_to_xyz(*dst_white)
    return np.linalg.inv(b) @ np.diag(d / s) @ b


def test_srgb_half_is_0_2140_linear():
    out = colour.convert(np.full((2, 2, 3), 0.5, np.float32), "srgb_texture")
    assert out.dtype == np.float32 and out.shape == (2, 2, 3)
    np.testing.assert_allclose(out, 0.2140, atol=1e-4)
    np.testing.assert_allclose(out, ((0.5 + 0.055) / 1.055) ** 2.4, atol=1e-6)


def test_srgb_curve_matches_iec_61966_2_1():
    x = np.linspace(0.0, 1.0, 1001, dtype=np.float32)
    out = colour.convert(np.repeat(x[:, None], 3, axis=1), "sRGB")  # USD's spelling
    ref = np.where(x > 0.04045, ((x.astype(np.float64) + 0.055) / 1.055) ** 2.4, x / 12.92)
    np.testing.assert_allclose(out[:, 1], ref, atol=2e-6)


def test_acescg_primary_into_lin_rec709():
    # AP1 -> linear Rec.709, derived here from the chromaticities: AP1 primaries and the ACES
    # white (x, y) = (0.32168, 0.33767) from SMPTE ST 2065-1 / Academy S-2014-004 (ACEScg);
    # Rec.709 primaries and D65 from ITU-R BT.709-6; Bradford chromatic adaptation.  Its first
    # column is (1.705051, -0.130256, -0.024003), the same as MaterialX's
    # ND_acescg_to_lin_rec709 matrix in libraries/cmlib/cmlib_ng.mtlx (1.705050992658,
    # -0.130256417507, -0.024003356805).
    ap1 = [(0.713, 0.293), (0.165, 0.830), (0.128, 0.044)]
    aces_white = (0.32168, 0.33767)
    rec709 = [(0.64, 0.33), (0.30, 0.60), (0.15, 0.06)]
    d65 = (0.3127, 0.3290)
    m = np.linalg.inv(_rgb_to_xyz(rec709, d65)) @ _bradford(aces_white, d65) @ _rgb_to_xyz(ap1, aces_white)
    np.testing.assert_allclose(m[:, 0], [1.705051, -0.130256, -0.024003], atol=1e-5)

    out = colour.convert(np.array([[1.0, 0.0, 0.0]], np.float32), "acescg", "lin_rec709")
    np.testing.assert_allclose(out[0], m[:, 0], atol=1e-4)
    # The whole matrix, and the ACES name for the same space.
    out = colour.convert(np.eye(3, dtype=np.float32), "ACEScg")
    np.testing.assert_allclose(out.T, m, atol=1e-4)


def test_g22_rec709_is_a_pure_power():
    out = colour.convert(np.array([0.5, 0.25, 1.0], np.float32), "g22_rec709")
    np.testing.assert_allclose(out, np.array([0.5, 0.25, 1.0]) ** 2.2, atol=1e-6)


def test_g18_ap1_is_gamma_1_8_over_acescg():
    x = np.array([[0.5, 0.3, 0.8]], np.float32)
    via = colour.convert(x.astype(np.float64) ** 1.8, "lin_ap1")
    np.testing.assert_allclose(colour.convert(x, "g18_ap1"), via, atol=1e-6)


def test_round_trip_lin_rec709_srgb_texture():
    rng = np.random.default_rng(1)
    x = rng.random((64, 64, 3), dtype=np.float32)
    enc = colour.convert(x, "lin_rec709", "srgb_texture")
    assert np.abs(enc - x).max() > 0.1
    np.testing.assert_allclose(colour.convert(enc, "srgb_texture", "lin_rec709"), x, atol=1e-5)


def test_acescg_working_space_round_trip():
    rng = np.random.default_rng(2)
    x = rng.random((100, 3), dtype=np.float32)
    ap1 = colour.convert(x, "lin_rec709", "acescg")
    np.testing.assert_allclose(colour.convert(ap1, "acescg", "lin_rec709"), x, atol=1e-5)
    np.testing.assert_allclose(colour.convert(x, "srgb_texture", "acescg"),
                               colour.convert(colour.convert(x, "srgb_texture"), "lin_rec709", "acescg"),
                               atol=1e-5)


@pytest.mark.parametrize("name", ["raw", "", "Raw", "data", "none", None])
def test_data_spaces_are_identity(name):
    rng = np.random.default_rng(3)
    x = rng.random((5, 7, 4), dtype=np.float32) * 3 - 1
    assert colour.is_data(name)
    out = colour.convert(x, name, "acescg")
    assert out is not x and not np.shares_memory(out, x)
    np.testing.assert_array_equal(out, x)
    # Any channel count passes through a data conversion.
    np.testing.assert_array_equal(colour.convert(x[..., :2], name), x[..., :2])


def test_same_space_is_identity_copy():
    x = np.array([[0.1, 0.5, 2.0]], np.float32)
    out = colour.convert(x, "lin_srgb", "lin_rec709")
    assert out is not x
    np.testing.assert_array_equal(out, x)


def test_alpha_preserved():
    x = np.array([[0.5, 0.5, 0.5, 0.25], [1.0, 0.2, 0.04, 1.5], [0.0, 0.0, 0.0, 0.0]], np.float32)
    for src in ("srgb_texture", "acescg", "g22_ap1"):
        out = colour.convert(x, src)
        np.testing.assert_array_equal(out[:, 3], x[:, 3])
        np.testing.assert_allclose(out[:, :3], colour.convert(x[:, :3], src), atol=0)
    np.testing.assert_allclose(colour.convert(x, "srgb_texture")[0, :3], 0.2140, atol=1e-4)


def test_input_not_modified():
    x = np.full((4, 3), 0.5, np.float32)
    colour.convert(x, "srgb_texture")
    np.testing.assert_array_equal(x, 0.5)


def test_unknown_name_is_input_error():
    with pytest.raises(InputError, match="not_a_space") as info:
        colour.convert(np.zeros((1, 3), np.float32), "not_a_space")
    assert "srgb_texture" in str(info.value) and "acescg" in str(info.value)
    with pytest.raises(InputError, match="bogus"):
        colour.canonical_colorspace("bogus")
    with pytest.raises(InputError, match="bogus"):
        colour.is_data("bogus")


@pytest.mark.parametrize("name,key", [
    ("srgb_texture", "srgb_texture"), ("sRGB", "srgb_texture"), ("srgb_rec709_scene", "srgb_texture"),
    ("lin_rec709", "lin_rec709"), ("lin_srgb", "lin_rec709"), ("lin_rec709_scene", "lin_rec709"),
    ("acescg", "acescg"), ("ACEScg", "acescg"), ("lin_ap1", "acescg"), ("lin_ap1_scene", "acescg"),
    ("g22_ap1", "g22_ap1"), ("g18_ap1", "g18_ap1"), ("adobergb", "adobergb"),
    ("srgb_displayp3", "srgb_displayp3"), ("lin_displayp3", "lin_displayp3"),
    ("  RAW ", "raw"), ("", "raw"), ("auto", "auto"),
])
def test_canonical_names(name, key):
    assert colour.canonical_colorspace(name) == key


@pytest.mark.parametrize("name", MATERIALX_SPACES)
def test_every_materialx_space_converts(name):
    x = np.linspace(0, 1, 30, dtype=np.float32).reshape(10, 3)
    out = colour.convert(x, name)
    assert out.shape == x.shape and np.isfinite(out).all()
    for dst in ("lin_rec709", "acescg"):
        assert colour.processor(name, dst) is colour.processor(name, dst)  # cached


def test_usd_auto_must_be_resolved_first():
    assert not colour.is_data("auto")
    with pytest.raises(InputError, match="auto"):
        colour.convert(np.zeros((1, 3), np.float32), "auto")


def test_non_finite_values_never_leave():
    x = np.array([[np.nan, np.inf, -np.inf], [0.5, 0.5, 0.5]], np.float32)
    for src in ("srgb_texture", "raw", "acescg"):
        assert np.isfinite(colour.convert(x, src)).all()


def test_convert_torch_matches_numpy():
    rng = np.random.default_rng(4)
    x = rng.random((50, 4), dtype=np.float32)
    t = torch.from_numpy(x.copy()).to(torch.float64)
    out = colour.convert_torch(t, "srgb_texture", "acescg")
    assert out.dtype == torch.float32 and out.device == t.device and out.shape == (50, 4)
    np.testing.assert_allclose(out.numpy(), colour.convert(x, "srgb_texture", "acescg"), atol=1e-6)
    np.testing.assert_array_equal(out[:, 3].numpy(), x[:, 3])
    raw = colour.convert_torch(t, "raw")
    assert raw.data_ptr() != t.data_ptr()
    np.testing.assert_allclose(raw.numpy(), x, atol=0)


_TEST_CONFIG = """\
ocio_profile_version: 2

roles:
  default: lin_rec709
  scene_linear: lin_rec709
  data: raw

file_rules:
  - !<Rule> {name: Default, colorspace: default}

displays:
  sRGB:
    - !<View> {name: Raw, colorspace: raw}

colorspaces:
  - !<ColorSpace>
    name: lin_rec709
    isdata: false

  - !<ColorSpace>
    name: srgb_texture
    isdata: false
    to_scene_reference: !<ExponentTransform> {value: [3, 3, 3, 1]}

  - !<ColorSpace>
    name: raw
    isdata: true
"""


def test_ocio_env_is_honoured(tmp_path, monkeypatch):
    path = tmp_path / "cube.ocio"
    path.write_text(_TEST_CONFIG)
    x = np.full((1, 3), 0.5, np.float32)
    saved = OCIO.GetCurrentConfig()
    try:
        np.testing.assert_allclose(colour.convert(x, "srgb_texture"), 0.2140, atol=1e-4)  # built-in

        monkeypatch.setenv("OCIO", str(path))
        assert colour.config_source() == f"$OCIO={path}"
        np.testing.assert_allclose(colour.convert(x, "srgb_texture"), 0.125, atol=1e-6)  # x ** 3
        assert OCIO.GetCurrentConfig().getColorSpace("srgb_texture") is not None
        # A gamma space the config lacks is built from its linear space.
        np.testing.assert_allclose(colour.convert(x, "g22_rec709"), 0.5 ** 2.2, atol=1e-6)
        # A space with no counterpart in the config is an InputError naming it.
        with pytest.raises(InputError, match="acescg"):
            colour.convert(x, "acescg")

        monkeypatch.delenv("OCIO")
        np.testing.assert_allclose(colour.convert(x, "srgb_texture"), 0.2140, atol=1e-4)
    finally:
        OCIO.SetCurrentConfig(saved)
        colour.processor.cache_clear()


def test_broken_ocio_env_is_input_error(tmp_path, monkeypatch):
    saved = OCIO.GetCurrentConfig()
    try:
        monkeypatch.setenv("OCIO", str(tmp_path / "missing.ocio"))
        with pytest.raises(InputError, match="OCIO"):
            colour.convert(np.zeros((1, 3), np.float32), "srgb_texture")
    finally:
        OCIO.SetCurrentConfig(saved)
        colour.processor.cache_clear()


def test_materialx_declared_spaces():
    import MaterialX as mx

    doc = mx.createDocument()
    assert colour.working_space(doc) == "lin_rec709"
    doc.setColorSpace("acescg")
    img = doc.addNode("image", "img", "color3")
    file_in = img.addInput("file", "filename")
    assert colour.working_space(img) == "acescg"
    assert colour.declared_colorspace(file_in) == "acescg"  # inherited: no conversion
    file_in.setColorSpace("srgb_texture")
    assert colour.declared_colorspace(file_in) == "srgb_texture"
    doc.setColorSpace("raw")
    with pytest.raises(InputError, match="working space"):
        colour.working_space(doc)
