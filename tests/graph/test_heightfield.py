"""``heighttonormal`` and ``bump`` compiled to torch (mtlx2neural.graph.heightfield).

MaterialX builds the normal from screen-space derivatives (dFdx/dFdy), which its per-point oracle (a compute
kernel) does not have, so these cases check against analytic heights instead: the normal of the height h
over the node's texcoord (s, t) is normalize(-dh'/ds, -dh'/dt, 1) * 0.5 + 0.5, h' = h * scale / 16, for any
non-degenerate screen parametrisation (see the module docstring of mtlx2neural.graph.heightfield).
A slow case also draws the node with MaterialX's GlslRenderer (real screen derivatives) and compares per
pixel.

Tolerances: analytic cases 1e-4 on the encoded normal: float32 sin/cos and autograd against a float64
formula; the sine's argument reaches 2 pi * 4.5 ~ 28 on the scaled texcoord, where float32 rounds it by ~2e-6,
and slopes reach ~20 (measured max 6.5e-5 there, 5e-6 over plain uv).  The image case 2e-4 against central
differences of the compiled image node with a step of 1e-3: float32 heights up to 2 carry ~2.4e-7 of
rounding, ~1.2e-4 in a difference quotient, times 5/16 and 1/2 in the encoding (measured max 1.8e-5).
"""

from __future__ import annotations

import math

import MaterialX as mx
import numpy as np
import pytest
import torch
from conftest import write_float_image

from mtlx2neural.codegen.glsl_render import gl_unavailable, read_exr, render_plan
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.reference import ReferenceMaterial

ORACLE_CATEGORIES = ("heighttonormal", "bump")  # analytic cases (screen derivatives: no MaterialX oracle)
ATOL = 1e-4  # see the module docstring


def _uv(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=g, dtype=torch.float64) * 2.0 - 0.5  # [-0.5, 1.5]^2: both signs


def _wave(doc, coord):
    """Nodes for h = sin(2 pi s) * t^2 of ``coord`` (a vector2 node): returns the height node."""
    sep = doc.addNode("separate2", f"{coord.getName()}_sep", "multioutput")
    sep.setConnectedNode("in", coord)
    sep.addOutput("outx", "float")
    sep.addOutput("outy", "float")
    arg = doc.addNode("multiply", f"{coord.getName()}_arg", "float")
    arg.addInput("in1", "float").setConnectedNode(sep)
    arg.getInput("in1").setOutputString("outx")
    arg.setInputValue("in2", 2.0 * math.pi)
    s = doc.addNode("sin", f"{coord.getName()}_sin", "float")
    s.setConnectedNode("in", arg)
    sq = doc.addNode("multiply", f"{coord.getName()}_sq", "float")
    for name in ("in1", "in2"):
        sq.addInput(name, "float").setConnectedNode(sep)
        sq.getInput(name).setOutputString("outy")
    h = doc.addNode("multiply", f"{coord.getName()}_h", "float")
    h.setConnectedNode("in1", s)
    h.setConnectedNode("in2", sq)
    return h


def _expected(s, t, ds_scale=(1.0, 1.0), scale=1.0):
    """Encoded normal of h = sin(2 pi s) t^2 over (s, t) (float64); ``ds_scale`` = d(coord)/d(node texcoord)."""
    k = scale / 16.0
    dhs = k * 2 * math.pi * np.cos(2 * math.pi * s) * t * t * ds_scale[0]
    dht = k * 2 * np.sin(2 * math.pi * s) * t * ds_scale[1]
    n = np.stack([-dhs, -dht, np.ones_like(s)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True) * 0.5 + 0.5


def _h2n(doc, height, scale, texcoord=None):
    n = doc.addNode("heighttonormal", "h2n", "vector3")
    n.setConnectedNode("in", height)
    n.setInputValue("scale", scale)
    if texcoord is not None:
        n.setConnectedNode("texcoord", texcoord)
    return n


def test_analytic_height_over_uv():
    doc = mx.createDocument()
    tc = doc.addNode("texcoord", "tc", "vector2")
    _h2n(doc, _wave(doc, tc), 3.0)
    out = compile_output(doc, "h2n")
    uv = _uv(512, seed=1)
    with torch.no_grad():  # the node works for callers that disable grad
        got = out(uv.float()).numpy()
    want = _expected(uv[:, 0].numpy(), uv[:, 1].numpy(), scale=3.0)
    assert np.ptp(want[:, 0]) > 0.3 and np.ptp(want[:, 1]) > 0.3  # tilted both ways: not vacuous
    np.testing.assert_allclose(got, want, atol=ATOL, rtol=0)
    assert not out(uv.float()).requires_grad  # values come back detached


def test_scaled_texcoord_chains_through_its_jacobian():
    doc = mx.createDocument()
    tc = doc.addNode("texcoord", "tc", "vector2")
    st = doc.addNode("multiply", "st", "vector2")
    st.setConnectedNode("in1", tc)
    st.setInputValue("in2", mx.Vector2(3.0, 2.0))
    h = _wave(doc, st)
    uv = _uv(512, seed=2)
    s, t = 3.0 * uv[:, 0].numpy(), 2.0 * uv[:, 1].numpy()
    # The node's texcoord is the scaled one: the normal is the gradient over (s, t) itself.
    _h2n(doc, h, 2.0, texcoord=st)
    got = compile_output(doc, "h2n")(uv.float()).detach().numpy()
    np.testing.assert_allclose(got, _expected(s, t, scale=2.0), atol=ATOL, rtol=0)
    # The node's texcoord is the plain uv: the gradient over uv is 3x and 2x steeper.
    doc.removeNode("h2n")
    _h2n(doc, h, 2.0)
    got = compile_output(doc, "h2n")(uv.float()).detach().numpy()
    np.testing.assert_allclose(got, _expected(s, t, ds_scale=(3.0, 2.0), scale=2.0), atol=ATOL, rtol=0)


def test_mirrored_and_degenerate_texcoords():
    doc = mx.createDocument()
    tc = doc.addNode("texcoord", "tc", "vector2")
    flip = doc.addNode("multiply", "flip", "vector2")  # u mirrored: the frame flips back up
    flip.setConnectedNode("in1", tc)
    flip.setInputValue("in2", mx.Vector2(-1.0, 1.0))
    h = _wave(doc, tc)
    _h2n(doc, h, 4.0, texcoord=flip)
    uv = _uv(256, seed=3)
    got = compile_output(doc, "h2n")(uv.float()).detach().numpy()
    # h = sin(2 pi u) v^2 with s = -u: dh/ds = -dh/du.
    np.testing.assert_allclose(got, _expected(uv[:, 0].numpy(), uv[:, 1].numpy(), ds_scale=(-1.0, 1.0),
                                              scale=4.0), atol=ATOL, rtol=0)
    assert (got[:, 2] > 0.5).all()
    # A constant texcoord has no frame: the flat normal, as MaterialX's degenerate case.
    doc.removeNode("h2n")
    const = doc.addNode("constant", "c", "vector2")
    const.setInputValue("value", mx.Vector2(0.3, 0.7))
    _h2n(doc, h, 4.0, texcoord=const)
    got = compile_output(doc, "h2n")(uv.float()).detach().numpy()
    np.testing.assert_allclose(got, np.tile([0.5, 0.5, 1.0], (256, 1)), atol=1e-7)


def test_uniform_height_is_flat_and_graphs_without_the_node_do_not_differentiate():
    doc = mx.createDocument()
    n = doc.addNode("heighttonormal", "h2n", "vector3")
    n.setInputValue("in", 0.7)
    out = compile_output(doc, "h2n")
    got = out(_uv(8, seed=4).float()).numpy()
    np.testing.assert_array_equal(got, np.tile(np.float32([0.5, 0.5, 1.0]), (8, 1)))
    doc = mx.createDocument()
    tc = doc.addNode("texcoord", "tc", "vector2")
    _wave(doc, tc)
    plain = compile_output(doc, "tc_h")
    assert not plain(_uv(8, seed=5).float()).requires_grad


def test_image_height_against_finite_differences(tmp_path):
    rng = np.random.default_rng(6)
    img = rng.uniform(0.0, 2.0, size=(8, 8, 1)).astype(np.float32)
    path = tmp_path / "height.exr"
    write_float_image(path, np.repeat(img, 3, -1))
    doc = mx.createDocument()
    im = doc.addNode("image", "hmap", "float")
    im.setInputValue("file", str(path), "filename")
    _h2n(doc, im, 5.0)
    normal = compile_output(doc, "h2n")
    height = compile_output(doc, "hmap")
    # Points at least 2 steps away from the texel-centre lines, where the bilinear slope jumps.
    g = torch.Generator().manual_seed(7)
    uv = torch.rand(4096, 2, generator=g, dtype=torch.float64)
    off = (uv * 8 - 0.5) % 1.0
    keep = ((off > 0.02) & (off < 0.98)).all(-1)
    uv = uv[keep][:300]
    assert uv.shape[0] >= 256
    step = 1e-3

    def h(x):
        return height(x.float()).double()[:, 0]

    du = torch.tensor([step, 0.0], dtype=torch.float64)
    dv = torch.tensor([0.0, step], dtype=torch.float64)
    k = 5.0 / 16.0
    n = torch.stack([-k * (h(uv + du) - h(uv - du)) / (2 * step), -k * (h(uv + dv) - h(uv - dv)) / (2 * step),
                     torch.ones(uv.shape[0], dtype=torch.float64)], -1)
    want = (n / n.norm(dim=-1, keepdim=True) * 0.5 + 0.5).numpy()
    got = normal(uv.float()).numpy()
    assert np.ptp(want[:, 0]) > 0.2  # the texture tilts the normal
    np.testing.assert_allclose(got, want, atol=2e-4, rtol=0)  # see the module docstring


def _surface(doc, with_bump: bool):
    ss = doc.addNode("standard_surface", "ss", "surfaceshader")
    ss.setInputValue("base", 1.0)
    ss.setInputValue("specular_roughness", 0.2)
    if with_bump:
        tc = doc.addNode("texcoord", "tc", "vector2")
        b = doc.addNode("bump", "bump", "vector3")
        b.setConnectedNode("height", _wave(doc, tc))
        b.setInputValue("scale", 1.0)
        # bump's heighttonormal keeps its scale of 1: h' = h / 16; give the wave some height.
        ss.setConnectedNode("normal", b)
    doc.addMaterialNode("M", ss)


def test_bump_into_standard_surface_tilts_the_shading():
    bumped, flat = mx.createDocument(), mx.createDocument()
    _surface(bumped, True)
    _surface(flat, False)
    amp = bumped.getNode("tc_h")
    scaled = bumped.addNode("multiply", "amp", "float")
    scaled.setConnectedNode("in1", amp)
    scaled.setInputValue("in2", 8.0)
    bumped.getNode("bump").setConnectedNode("height", scaled)
    cm = compile_material(bumped, "M")
    assert any(cm.graph[i].category == "heighttonormal" for i in cm.spatial_nodes)
    m_b, m_f = ReferenceMaterial(cm), ReferenceMaterial(compile_material(flat, "M"))
    # u = 0 (slope in u maximal: dh/du = 8 * 2 pi * v^2 / 16), v = 0.8; a near-mirror configuration.
    uv = torch.tensor([[0.0, 0.8], [0.25, 0.8]])
    wi = torch.nn.functional.normalize(torch.tensor([[0.4, 0.0, 0.9]]), dim=-1).expand(2, 3)
    wo = wi * torch.tensor([-1.0, -1.0, 1.0])
    with torch.no_grad():
        fb, ff = m_b.eval(wi, wo, uv=uv), m_f.eval(wi, wo, uv=uv)
    assert torch.isfinite(fb).all()
    assert (fb[0] - ff[0]).abs().max() > 0.05 * ff[0].abs().max()  # tilted: the specular peak moves away
    # At u = 0.25 the u-slope is 0 but the v-slope is 8 * 2 * 0.8 / 16 = 0.8: tilted too, in v.
    assert (fb[1] - ff[1]).abs().max() > 0.05 * ff[1].abs().max()


def _unlit(doc, src):
    """Wire ``src`` (a vector3 node) into an unlit material's emission colour (the value passes through)."""
    c = doc.addNode("convert", "to_colour", "color3")
    c.setConnectedNode("in", src)
    s = doc.addNode("surface_unlit", "s", "surfaceshader")
    s.setConnectedNode("emission_color", c)
    doc.addMaterialNode("M", s)


@pytest.mark.slow
def test_heighttonormal_matches_materialx_glsl_render(tmp_path):
    """MaterialX's GlslRenderer draws the node's output on its sphere (real dFdx/dFdy over 2x2 pixel quads);
    a second draw writes each pixel's interpolated texcoord, at which the torch node is evaluated.

    Tolerance: median 1e-3 and 99th percentile 1e-2 of the per-pixel max channel error on the encoded normal
    (measured at 256 px over ~9k interior pixels: median 2.7e-4, p99 4.5e-3, max 2.2e-2).  A quad's derivatives are one-sided differences over a pixel (first
    order: d2h/du2 ~ 4 pi^2 against dh/du ~ 2 pi over ~2e-3 in u per pixel, ~0.5% of the slope), and the
    tessellated sphere's uv is linear per triangle, so quads straddling a triangle edge see a kinked
    texcoord (the outliers)."""
    reason = gl_unavailable()
    if reason:
        pytest.skip(f"MaterialX's GLSL renderer cannot run here: {reason}")
    height_doc = mx.createDocument()
    tc = height_doc.addNode("texcoord", "tc", "vector2")
    _unlit(height_doc, _h2n(height_doc, _wave(height_doc, tc), 4.0))
    uv_doc = mx.createDocument()
    tc = uv_doc.addNode("texcoord", "tc", "vector2")
    uvz = uv_doc.addNode("convert", "uvz", "vector3")
    uvz.setConnectedNode("in", tc)
    _unlit(uv_doc, uvz)
    jobs = []
    for name, doc in (("height", height_doc), ("uv", uv_doc)):
        mx.writeToXmlFile(doc, str(tmp_path / f"{name}.mtlx"))
        jobs.append({"mtlx": str(tmp_path / f"{name}.mtlx"), "out": str(tmp_path / f"{name}.exr"), "size": 256,
                     "frames": 0})
    render_plan({"renders": jobs})
    gl, uv_img = read_exr(tmp_path / "height.exr"), read_exr(tmp_path / "uv.exr")
    covered = uv_img[..., 3] > 0.5
    inner = covered.copy()  # the pixel and its four neighbours covered: no silhouette quads
    inner[1:-1, 1:-1] &= covered[:-2, 1:-1] & covered[2:, 1:-1] & covered[1:-1, :-2] & covered[1:-1, 2:]
    u, v = uv_img[..., 0], uv_img[..., 1]
    inner &= (np.abs(u - 0.5) < 0.35) & (v > 0.2) & (v < 0.8)  # away from the u seam and the poles
    assert inner.sum() >= 256
    got = compile_output(height_doc, "h2n")(torch.from_numpy(uv_img[inner][:, :2].copy())).numpy()
    want = gl[inner][:, :3]
    assert np.ptp(want[:, 0]) > 0.2 and np.ptp(want[:, 1]) > 0.2  # the render is tilted both ways
    err = np.abs(got - want).max(-1)
    stats = f"median {np.median(err):.2e}, p99 {np.percentile(err, 99):.2e}, max {err.max():.2e}"
    assert np.median(err) < 1e-3 and np.percentile(err, 99) < 1e-2, stats
