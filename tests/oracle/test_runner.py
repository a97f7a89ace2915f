"""Tests for the MaterialX Slang oracle (mtlx2neural.oracle.runner).

The oracle runs MaterialX's own generated Slang shader on slangpy's CPU device.  Each distinct
material costs one Slang compile (a few seconds on a 2-core CPU), so this file compiles only five
shaders.  Everything is skipped when slangpy's CPU device is unavailable.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mtlx2neural.oracle import runner as mtlx_oracle
from mtlx2neural.oracle.runner import mtlx_slang_eval, oracle_available

mx = pytest.importorskip("MaterialX")

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO.parent / "shared" / "assets" / "materialx" / "resources" / "Materials" / "Examples"
DEFAULT_MTLX = EXAMPLES / "StandardSurface" / "standard_surface_default.mtlx"


@pytest.fixture(scope="module", autouse=True)
def _require_oracle():
    ok, reason = oracle_available()
    if not ok:
        pytest.skip(f"MaterialX Slang oracle unavailable: {reason}")


def _doc(xml: str):
    doc = mx.createDocument()
    mx.readFromXmlString(doc, xml)
    return doc


def _upper_hemisphere(rng: np.random.Generator, n: int, min_z: float = 0.02) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.maximum(v[:, 2], min_z)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _diffuse_xml(color, emission=None) -> str:
    edf = ""
    edf_input = ""
    if emission is not None:
        edf = (
            '  <uniform_edf name="glow" type="EDF">\n'
            f'    <input name="color" type="color3" value="{", ".join(map(str, emission))}"/>\n'
            "  </uniform_edf>\n"
        )
        edf_input = '    <input name="edf" type="EDF" nodename="glow"/>\n'
    return f"""<?xml version="1.0"?>
<materialx version="1.39">
  <oren_nayar_diffuse_bsdf name="diffuse" type="BSDF">
    <input name="color" type="color3" value="{", ".join(map(str, color))}"/>
    <input name="roughness" type="float" value="0.0"/>
  </oren_nayar_diffuse_bsdf>
{edf}  <surface name="surf" type="surfaceshader">
    <input name="bsdf" type="BSDF" nodename="diffuse"/>
{edf_input}  </surface>
  <surfacematerial name="Lambert" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="surf"/>
  </surfacematerial>
</materialx>
"""


COLOR = np.array([0.2, 0.5, 0.8])


def test_lambert_matches_cosine_over_pi_and_ignores_emission():
    rng = np.random.default_rng(7)
    wi = _upper_hemisphere(rng, 256)
    wo = _upper_hemisphere(rng, 256)
    expected = COLOR[None, :] * wo[:, 2:3] / math.pi

    doc = _doc(_diffuse_xml(COLOR))
    got = mtlx_slang_eval(doc, "Lambert", wi, wo)
    assert got.shape == (256, 3) and got.dtype == np.float64
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=0)

    # A second call reuses the compiled kernel.
    n_kernels = len(mtlx_oracle._kernels)
    again = mtlx_slang_eval(doc, "Lambert", wi[:17], wo[:17])
    assert len(mtlx_oracle._kernels) == n_kernels
    np.testing.assert_array_equal(again, got[:17])

    # Emission much brighter than the reflection is removed.
    glowing = _doc(_diffuse_xml(COLOR, emission=(5.0, 3.0, 1.0)))
    got_em = mtlx_slang_eval(glowing, "Lambert", wi, wo)
    np.testing.assert_allclose(got_em, expected, rtol=1e-6, atol=0)


def test_input_validation():
    doc = _doc(_diffuse_xml(COLOR))
    with pytest.raises(ValueError):
        mtlx_slang_eval(doc, "Lambert", np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError):
        mtlx_slang_eval(doc, "Lambert", np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(mtlx_oracle.OracleError):
        mtlx_slang_eval(doc, "NoSuchMaterial", np.zeros((1, 3)), np.zeros((1, 3)))


@pytest.mark.skipif(not DEFAULT_MTLX.is_file(), reason=f"{DEFAULT_MTLX} not present")
def test_standard_surface_default_is_plausible():
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(DEFAULT_MTLX))
    rng = np.random.default_rng(3)
    wi = _upper_hemisphere(rng, 512)
    wo = _upper_hemisphere(rng, 512)
    got = mtlx_slang_eval(doc, "Default", wi, wo)
    assert got.shape == (512, 3)
    assert np.all(np.isfinite(got))
    assert np.all(got >= 0.0)

    # Specular peak: viewer at 45 degrees; compare the mirror direction with directions at the
    # same elevation (so the same cosine) but rotated in azimuth.
    s = math.sqrt(0.5)
    view = np.array([[s, 0.0, s]] * 3)
    light = np.array([[-s, 0.0, s], [0.0, s, s], [s, 0.0, s]])
    peak, side, back = mtlx_slang_eval(doc, "Default", view, light)
    assert np.all(peak > 2.0 * side)
    assert np.all(peak > 2.0 * back)
    # Off the peak the grey base dominates: roughly 0.8 * cos / pi, scaled by the specular layer.
    diffuse_level = 0.8 * s / math.pi
    assert np.all(side > 0.5 * diffuse_level) and np.all(side < 1.5 * diffuse_level)


def _ggx_dielectric_reference(wi, wo, alpha, ior, tint):
    """MaterialX's dielectric_bsdf reflection lobe (anisotropic GGX, height-correlated Smith with
    the averaged alpha, exact dielectric Fresnel, analytic-fit energy compensation), cosine
    included, written out independently in numpy."""
    ax, ay = alpha
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    n_v = np.clip(wi[:, 2], 1e-8, 1.0)
    n_l = np.clip(wo[:, 2], 1e-8, 1.0)
    v_h = np.clip(np.sum(wi * h, axis=1), 1e-8, 1.0)
    d = 1.0 / (math.pi * ax * ay * ((h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2 + h[:, 2] ** 2) ** 2)
    a = math.sqrt(ax * ay)
    a2 = a * a
    g = 2 * n_l * n_v / (n_v * np.sqrt(a2 + (1 - a2) * n_l**2) + n_l * np.sqrt(a2 + (1 - a2) * n_v**2))
    gg = np.sqrt(ior * ior + v_h**2 - 1)
    f = 0.5 * ((gg - v_h) / (gg + v_h)) ** 2 * (1 + (((gg + v_h) * v_h - 1) / ((gg - v_h) * v_h + 1)) ** 2)
    # Directional albedo of GGX with F0 = F90 = 1 (MaterialX's analytic rational fit).
    x, y = n_v, a
    coef = np.array(
        [
            [0.1003, 0.9345, 1.0, 1.0],
            [-0.6303, -2.323, -1.765, 0.2281],
            [9.748, 2.229, 8.263, 15.94],
            [-2.038, -3.748, 11.53, -55.83],
            [29.34, 1.424, 28.96, 13.08],
            [-8.245, -0.7684, -7.507, 41.26],
            [-26.44, 1.436, -36.11, 54.9],
            [19.99, 0.2913, 15.86, 300.2],
            [-5.448, 0.6286, 33.37, -285.1],
        ]
    )
    terms = np.stack(
        [
            np.ones_like(x),
            x,
            y * np.ones_like(x),
            x * y,
            x * x,
            y * y * np.ones_like(x),
            x * x * y,
            x * y * y,
            x * x * y * y,
        ],
        axis=1,
    )
    r = terms @ coef
    ab = np.clip(r[:, :2] / r[:, 2:], 0.0, 1.0)
    e_ss = ab[:, 0] + ab[:, 1]
    comp = 1.0 + f * (1.0 - e_ss) / e_ss
    return (d * f * g * comp / (4.0 * n_v))[:, None] * np.asarray(tint)[None, :]


def test_anisotropic_dielectric_matches_numpy_ggx_in_tangent_frame():
    """Checks the frame conventions: tangent = +X, view = wi, light = wo (and emission removal)."""
    xml = """<?xml version="1.0"?>
<materialx version="1.39">
  <dielectric_bsdf name="spec" type="BSDF">
    <input name="tint" type="color3" value="1.0, 0.9, 0.8"/>
    <input name="ior" type="float" value="1.6"/>
    <input name="roughness" type="vector2" value="0.2, 0.5"/>
  </dielectric_bsdf>
  <uniform_edf name="glow" type="EDF">
    <input name="color" type="color3" value="3, 2, 1"/>
  </uniform_edf>
  <surface name="surf" type="surfaceshader">
    <input name="bsdf" type="BSDF" nodename="spec"/>
    <input name="edf" type="EDF" nodename="glow"/>
  </surface>
  <surfacematerial name="Coat" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="surf"/>
  </surfacematerial>
</materialx>
"""
    rng = np.random.default_rng(11)
    wi = _upper_hemisphere(rng, 256, min_z=0.05)
    wo = _upper_hemisphere(rng, 256, min_z=0.05)
    got = mtlx_slang_eval(_doc(xml), "Coat", wi, wo)
    ref = _ggx_dielectric_reference(wi, wo, (0.2, 0.5), 1.6, (1.0, 0.9, 0.8))
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-7)


# The second spelling is how a library authored on a case-insensitive file system names the file:
# the oracle must read the one file that matches, as the graph compiler does, not its default.
@pytest.mark.parametrize("named", ["quad.exr", "Quad.EXR"])
def test_image_texture_uses_lower_left_uv_origin(tmp_path, named, recwarn):
    oiio = pytest.importorskip("OpenImageIO")
    # 2x2 image, rows top first: red, green / blue, white.
    pixels = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], dtype=np.float32)
    path = tmp_path / "quad.exr"
    out = oiio.ImageOutput.create(str(path))
    assert out is not None
    out.open(str(path), oiio.ImageSpec(2, 2, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    xml = f"""<?xml version="1.0"?>
<materialx version="1.39" colorspace="lin_rec709">
  <constant name="uv" type="vector2">
    <input name="value" type="vector2" value="0.25, 0.75"/>
  </constant>
  <image name="img" type="color3">
    <input name="file" type="filename" value="{(tmp_path / named).as_posix()}"/>
    <input name="texcoord" type="vector2" nodename="uv"/>
    <input name="filtertype" type="string" value="closest"/>
  </image>
  <oren_nayar_diffuse_bsdf name="diffuse" type="BSDF">
    <input name="color" type="color3" nodename="img"/>
  </oren_nayar_diffuse_bsdf>
  <surface name="surf" type="surfaceshader">
    <input name="bsdf" type="BSDF" nodename="diffuse"/>
  </surface>
  <surfacematerial name="Textured" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="surf"/>
  </surfacematerial>
</materialx>
"""
    up = np.array([[0.0, 0.0, 1.0]])
    got = mtlx_slang_eval(_doc(xml), "Textured", up, up) * math.pi
    # uv (0.25, 0.75) is the top-left texel: MaterialX puts the uv origin at the lower left.
    np.testing.assert_allclose(got, [[1.0, 0.0, 0.0]], atol=1e-6)
    assert not [w for w in recwarn if "cannot be read" in str(w.message)]
