"""Emission and opacity beside the BSDF (mtlx2neural.graph.surface_terms) against MaterialX's own shading.

Each material is a small MaterialX document for one shading model. The reference's ``emission`` and
``opacity`` at uv (0.5, 0.5) are checked against known values, and, where slangpy's CPU device runs the
oracle, against MaterialX's generated Slang with the light off, whose colour is emission * opacity
(tolerance 1e-5 relative plus 1e-6: float32 arithmetic of the same formulas)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.oracle.runner import mtlx_slang_unlit, oracle_available

mx = pytest.importorskip("MaterialX")

HEAD = '<?xml version="1.0"?>\n<materialx version="1.39">\n'


def _material(shader: str, body: str, inputs: str) -> str:
    return (HEAD + f'  <{shader} name="sh" type="surfaceshader">\n{inputs}  </{shader}>\n{body}'
            '  <surfacematerial name="M" type="material">\n'
            '    <input name="surfaceshader" type="surfaceshader" nodename="sh"/>\n'
            '  </surfacematerial>\n</materialx>\n')


def _inp(name, typ, value):
    return f'    <input name="{name}" type="{typ}" value="{value}"/>\n'


CASES = {
    # name: (xml, expected emission or None, expected opacity or None)
    "usd_emissive_cutout_hidden": (_material("UsdPreviewSurface", "", _inp("emissiveColor", "color3", "0.8, 0.3, 0.1")
                                            + _inp("opacity", "float", "0.3") + _inp("opacityThreshold", "float", "0.5")),
                                   (0.8, 0.3, 0.1), 0.0),
    "usd_cutout_kept": (_material("UsdPreviewSurface", "", _inp("opacity", "float", "0.7")
                                  + _inp("opacityThreshold", "float", "0.5")), None, 1.0),
    # opacityMode 0 (transparent) without a threshold: MaterialX turns opacity into transmission, not coverage
    "usd_transparent": (_material("UsdPreviewSurface", "", _inp("opacity", "float", "0.4")), None, 1.0),
    "usd_presence": (_material("UsdPreviewSurface", "", _inp("opacity", "float", "0.4")
                               + _inp("opacityMode", "integer", "1")), None, 0.4),
    "gltf_mask": (_material("gltf_pbr", "", _inp("emissive", "color3", "1, 0.5, 0.25")
                            + _inp("emissive_strength", "float", "2") + _inp("alpha", "float", "0.3")
                            + _inp("alpha_mode", "integer", "1")), (2.0, 1.0, 0.5), 0.0),
    "gltf_blend": (_material("gltf_pbr", "", _inp("alpha", "float", "0.3") + _inp("alpha_mode", "integer", "2")),
                   None, 0.3),
    "standard_surface_coated_emission": (_material("standard_surface", "", _inp("emission", "float", "2")
                                                   + _inp("emission_color", "color3", "0.5, 0.5, 1")
                                                   + _inp("coat", "float", "0.5") + _inp("opacity", "color3",
                                                                                         "0.5, 0.5, 0.5")),
                                         None, 0.5),
    "open_pbr_emission": (_material("open_pbr_surface", "", _inp("emission_luminance", "float", "500")
                                    + _inp("emission_color", "color3", "1, 0.8, 0.6")
                                    + _inp("geometry_opacity", "float", "0.6")), None, 0.6),
    "unlit": (_material("surface_unlit", "", _inp("emission", "float", "2")
                        + _inp("emission_color", "color3", "0.1, 0.2, 0.3") + _inp("opacity", "float", "0.5")),
              (0.2, 0.4, 0.6), 0.5),
}


def _load(tmp_path, name, xml):
    path = tmp_path / f"{name}.mtlx"
    path.write_text(xml)
    return m2n.load_reference(path), path


@pytest.mark.parametrize("name", sorted(CASES))
def test_emission_and_opacity_match_materialx(tmp_path, name):
    xml, emission, opacity = CASES[name]
    ref, path = _load(tmp_path, name, xml)
    at = torch.tensor([[0.5, 0.5]])
    e, o = ref.emission(at), ref.opacity(at)
    if emission is not None:
        np.testing.assert_allclose(e.numpy()[0], emission, rtol=1e-6, atol=1e-6)
    if opacity is not None:
        assert o is not None if opacity < 1 else o is None, (name, o)
        if o is not None:
            np.testing.assert_allclose(float(o[0]), opacity, rtol=1e-6, atol=1e-6)
    ok, reason = oracle_available()
    if not ok:
        pytest.skip(f"MaterialX Slang oracle unavailable: {reason} (the known values above were checked)")
    doc = mx.createDocument()
    mx.readFromXmlString(doc, xml)
    mine = (e if e is not None else torch.zeros(1, 3)) * (o[:, None] if o is not None else 1.0)
    theirs = mtlx_slang_unlit(doc, "M", np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(mine.numpy(), theirs, rtol=1e-5, atol=1e-6)


def test_textured_emission_reads_its_image(tmp_path):
    """An emission colour read from an image varies with uv as the image does (two texels, left and right)."""
    import OpenImageIO as oiio

    img = tmp_path / "glow.exr"
    out = oiio.ImageOutput.create(str(img))
    out.open(str(img), oiio.ImageSpec(2, 1, 3, "float"))
    out.write_image(np.array([[[1.0, 0.0, 0.0], [0.0, 0.0, 4.0]]], dtype=np.float32))
    out.close()
    body = ('  <image name="tex" type="color3">\n    <input name="file" type="filename" value="glow.exr"/>\n'
            '    <input name="filtertype" type="string" value="closest"/>\n  </image>\n')
    xml = _material("UsdPreviewSurface", body, '    <input name="emissiveColor" type="color3" nodename="tex"/>\n')
    ref, _ = _load(tmp_path, "textured", xml)
    e = ref.emission(torch.tensor([[0.25, 0.5], [0.75, 0.5]]))
    np.testing.assert_allclose(e.numpy(), [[1.0, 0.0, 0.0], [0.0, 0.0, 4.0]], atol=1e-6)
    assert ref.describe()["surface"]["emission"] == "textured"


def test_direction_dependent_emission_is_refused_not_dropped(tmp_path):
    body = ('  <conical_edf name="cone" type="EDF">\n' + _inp("color", "color3", "3, 3, 3").replace("    ", "    ")
            + '  </conical_edf>\n  <oren_nayar_diffuse_bsdf name="d" type="BSDF"/>\n')
    xml = (HEAD + body + '  <surface name="sh" type="surfaceshader">\n'
           '    <input name="bsdf" type="BSDF" nodename="d"/>\n    <input name="edf" type="EDF" nodename="cone"/>\n'
           '  </surface>\n  <surfacematerial name="M" type="material">\n'
           '    <input name="surfaceshader" type="surfaceshader" nodename="sh"/>\n  </surfacematerial>\n</materialx>\n')
    ref, _ = _load(tmp_path, "cone", xml)
    d = ref.describe()
    assert d["surface"]["refused"] and "conical_edf" in d["surface"]["refused"][0]
    assert any("conical_edf" in a for a in d["approximations"])
    assert ref.emission(torch.tensor([[0.5, 0.5]])) is None


def test_opacity_is_not_folded_into_the_brdf(tmp_path):
    """A half-transparent surface reflects like the opaque one: coverage is applied by the consumer."""
    xml, _, _ = CASES["gltf_blend"]
    ref, _ = _load(tmp_path, "blend", xml)
    opaque, _ = _load(tmp_path, "opaque", _material("gltf_pbr", "", ""))
    wi = torch.tensor([[0.3, 0.1, 0.9]])
    wo = torch.tensor([[-0.2, 0.4, 0.8]])
    torch.testing.assert_close(ref.eval(wi, wo), opaque.eval(wi, wo), rtol=1e-6, atol=1e-7)
    assert opaque.opacity(torch.tensor([[0.5, 0.5]])) is None and opaque.emission(torch.tensor([[0.5, 0.5]])) is None


def test_inspect_warns_about_refused_emission(tmp_path):
    """What a user sees: `inspect` (and so the conversion's plan) warns, naming the conical EDF."""
    from mtlx2neural.pipeline.inspection import inspect_asset

    body = ('  <conical_edf name="cone" type="EDF">\n' + _inp("color", "color3", "3, 3, 3")
            + '  </conical_edf>\n  <oren_nayar_diffuse_bsdf name="d" type="BSDF"/>\n')
    xml = (HEAD + body + '  <surface name="sh" type="surfaceshader">\n'
           '    <input name="bsdf" type="BSDF" nodename="d"/>\n    <input name="edf" type="EDF" nodename="cone"/>\n'
           '  </surface>\n  <surfacematerial name="M" type="material">\n'
           '    <input name="surfaceshader" type="surfaceshader" nodename="sh"/>\n  </surfacematerial>\n</materialx>\n')
    (tmp_path / "cone.mtlx").write_text(xml)
    report = inspect_asset(tmp_path / "cone.mtlx")
    assert any("conical_edf 'cone'" in w and "left out" in w for w in report["materials"][0]["warnings"])
