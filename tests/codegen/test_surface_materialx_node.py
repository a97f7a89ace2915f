"""Emission and opacity in the neural material's MaterialX document (codegen.materialx_node): the surface
node's ``edf`` (a ``uniform_edf`` of the emission) and ``opacity`` (the opacity map, a cut-out's through an
``ifgreatereq`` at 0.5), checked in MaterialX's GlslRenderer (Mesa llvmpipe under Xvfb, as
tests/codegen/test_materialx_node.py) against its render of the original MaterialX material.

Two originals, UsdPreviewSurfaces with a black diffuse colour, rendered with no light and a black
environment, so the image is what they emit times their coverage:

- ``glow``: emissiveColor from an 8x8 EXR (left half orange, right half blue, the bottom half at half
  the radiance: a mirrored or flipped lookup shows), opaque;
- ``cut``: a constant emissiveColor and an 8x8 opacity texture (covered where u < 0.5 and v > 0.25) with
  opacityThreshold 0.5: a cut-out (UsdPreviewSurface's graph tests ``opacity >= opacityThreshold``).

Each is converted as the pipeline does: ``build_surface_maps`` of the compiled original on the 8x8 latent
grid, a NeuralMaterial (seeded, its decoder's output bias at -30, so its reflectance is negligible; with no
light it is not seen anyway) exported with ``write_surface_files`` and given its node. The neural documents'
renders must be within HDR FLIP 0.05 of the originals' (measured 0.0: both read the same texel values, the
emission in half precision, with the same image nodes). Pixels are checked against the torch renderer's
image of the converted model (``render_scene``, 16 jittered samples per pixel): where all of a pixel's
samples see one texel colour (or all see nothing), MaterialX's pixel has that colour (or shows the
background).
"""

from __future__ import annotations

import sys
from pathlib import Path

import MaterialX as mx
import MaterialX.PyMaterialXGenShader as mx_gen
import numpy as np
import pytest
import torch

# The GL probe of test_materialx_node.py: one place says how a GL context is found.
from test_materialx_node import gl_reason

from mtlx2neural.codegen.glsl_render import read_exr, render_plan, write_exr
from mtlx2neural.codegen.materialx_node import (
    generate_node_shader,
    load_node_document,
    node_names,
    write_materialx_node,
)
from mtlx2neural.errors import InputError
from mtlx2neural.export.latents import write_latent_textures
from mtlx2neural.export.surface_files import write_surface_files
from mtlx2neural.formats.weights import write_weights
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.library import with_libraries
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.renderer import render_scene
from mtlx2neural.textures.surface_maps import (
    SurfaceMaps,
    build_surface_maps,
    level_shapes,
)

ORANGE, BLUE = np.array([2.0, 0.75, 0.25]), np.array([0.125, 0.5, 1.0])  # exact in half precision
GLOW = (0.9, 0.6, 0.3)
SIZE = 64


def original(root: Path, name: str, emissive=None, opacity_file: str | None = None) -> Path:
    """A UsdPreviewSurface with a black diffuse colour, the emissive colour ``emissive`` (a file name: an
    image of it) and, with ``opacity_file``, that texture's opacity alpha-tested at 0.5."""
    doc = mx.createDocument()
    shader = doc.addNode("UsdPreviewSurface", f"SR_{name}", "surfaceshader")
    shader.setInputValue("diffuseColor", mx.Color3(0, 0, 0), "color3")
    if isinstance(emissive, str):
        image = doc.addNode("image", "emission", "color3")
        image.setInputValue("file", emissive, "filename")
        shader.setConnectedNode("emissiveColor", image)
    else:
        shader.setInputValue("emissiveColor", mx.Color3(*emissive), "color3")
    if opacity_file:
        image = doc.addNode("image", "opacity", "float")
        image.setInputValue("file", opacity_file, "filename")
        shader.setConnectedNode("opacity", image)
        shader.setInputValue("opacityThreshold", 0.5, "float")
    doc.addMaterialNode(f"M_{name}", shader)
    path = root / f"{name}.mtlx"
    mx.writeToXmlFile(doc, str(path))
    return path


def small_model(surface: SurfaceMaps | None) -> NeuralMaterial:
    """A seeded 8x8 NeuralMaterial whose decoder outputs exp(-33): no visible reflection."""
    torch.manual_seed(0)
    model = NeuralMaterial((8, 8), in_dim=0, latent_dim=8, frames=2, decoder="2x16").train(False)
    with torch.no_grad():
        model.decoder.net[-1].bias.fill_(-30.0)
    model.surface = surface
    return model


def export(model: NeuralMaterial, folder: Path, name: str) -> Path:
    """The model's export (latents, weights, surface maps) in ``folder`` and its node in ``folder/materialx``."""
    write_latent_textures(list(model.latents.levels), folder)
    write_weights(model, folder)
    write_surface_files(model.surface, folder)
    return write_materialx_node(folder, name, folder / "materialx")


def converted(path: Path, material: str, folder: Path, name: str) -> tuple[Path, NeuralMaterial]:
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    model = small_model(build_surface_maps(compile_material(doc, material), (8, 8)))
    return export(model, folder, name), model


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    """{"glow" | "cut": (original .mtlx, neural .mtlx, converted model)}."""
    root = tmp_path_factory.mktemp("surface_node")
    glow = np.zeros((8, 8, 3), np.float32)
    glow[:, :4], glow[:, 4:] = ORANGE, BLUE
    glow[4:] *= 0.5
    write_exr(root / "glow.exr", glow)
    mask = np.zeros((8, 8, 1), np.float32)
    mask[:6, :4] = 1.0  # u < 0.5 and v > 0.25 (rows from the top)
    write_exr(root / "mask.exr", mask)
    out = {}
    for name, path in (("glow", original(root, "glow", "glow.exr")),
                       ("cut", original(root, "cut", GLOW, "mask.exr"))):
        out[name] = (path, *converted(path, f"M_{name}", root / name / "neural", name.title()))
    return out


# ------------------------------------------------------------------------------ the document


def test_document_wires_emission_and_cutout(materials):
    """The cut-out: the surface's edf is a uniform_edf of the constant emission, its opacity the
    ``ifgreatereq`` of the copied opacity map (every MIP level copied) at 0.5; the textured emission: an
    image of the copied emission map in lin_rec709. Both validate, are transparent / opaque surfaces for
    MaterialX, and generate GLSL and Slang."""
    _, mtlx, model = materials["cut"]
    n = node_names("Cut")
    doc = load_node_document(mtlx)
    ok, message = with_libraries(doc).validate()
    assert ok, message
    surface = doc.getNode(n.surface)
    edf = surface.getConnectedNode("edf")
    assert edf.getCategory() == "uniform_edf" and edf.getInput("color").getValue() == mx.Color3(*GLOW)
    cutout = surface.getConnectedNode("opacity")
    assert cutout.getCategory() == "ifgreatereq" and cutout.getInputValue("value2") == 0.5
    assert (cutout.getInputValue("in1"), cutout.getInputValue("in2")) == (1.0, 0.0)
    image = cutout.getConnectedNode("value1")
    assert image.getCategory() == "image" and image.getType() == "float" and image.getInputValue("file") == "opacity.exr"
    copied = read_mip_chain(mtlx.parent / "opacity.exr", 1, what="opacity map")
    assert len(copied) == len(model.surface.opacity_levels) == len(level_shapes(8, 8))
    for level, ours in zip(copied, model.surface.opacity_levels):
        np.testing.assert_array_equal(level[..., 0].astype(np.float32), ours[0].half().float().numpy())
    assert mx_gen.isTransparentSurface(doc.getNode(n.material), "genglsl")

    _, mtlx, _ = materials["glow"]
    n = node_names("Glow")
    doc = load_node_document(mtlx)
    surface = doc.getNode(n.surface)
    image = surface.getConnectedNode("edf").getConnectedNode("color")
    assert image.getName() == n.emission and image.getInputValue("file") == "emission.exr"
    assert image.getInput("file").getColorSpace() == "lin_rec709"
    assert surface.getInput("opacity") is None and (mtlx.parent / "emission.exr").is_file()
    assert not mx_gen.isTransparentSurface(doc.getNode(n.material), "genglsl")
    for target in ("genglsl", "genslang"):
        pixel = generate_node_shader(mtlx, target).getSourceCode("pixel")
        assert "$" not in pixel and "mx_uniform_edf" in pixel


def test_constant_and_blended_opacity(tmp_path):
    """A blend's opacity map feeds the surface directly; a constant cut-out is alpha-tested when written;
    a model whose textured maps were not written beside its latents is refused, naming what to do."""
    blend = SurfaceMaps(emission_constant=(1.0, 2.0, 3.0), alpha_mode="blend",
                        opacity_levels=[torch.full((1, h, w), 0.25) for h, w in level_shapes(8, 8)])
    doc = load_node_document(export(small_model(blend), tmp_path / "blend", "Blend"))
    surface = doc.getNode(node_names("Blend").surface)
    assert surface.getConnectedNode("opacity").getCategory() == "image"
    constant = small_model(SurfaceMaps(opacity_constant=0.0, alpha_mode="mask"))
    doc = load_node_document(export(constant, tmp_path / "constant", "Constant"))
    surface = doc.getNode(node_names("Constant").surface)
    assert surface.getInputValue("opacity") == 0.0 and surface.getInput("edf") is None
    folder = tmp_path / "model"
    textured = small_model(blend)
    write_latent_textures(list(textured.latents.levels), folder)
    with pytest.raises(InputError, match="surface.json"):
        write_materialx_node(textured, "Textured", folder)


# ------------------------------------------------------------------------------ MaterialX's renderer


@pytest.fixture(scope="module")
def renders(materials, gl_context):
    """GlslRenderer images [SIZE, SIZE, 4] (RGB, alpha = covered) of each original and neural document,
    with no light and a black environment, and the torch renderer's images of the converted models."""
    root = materials["glow"][0].parent
    keys, jobs = [], []
    for name, (orig, neural, _) in materials.items():
        for label, path in (("original", orig), ("neural", neural)):
            keys.append((name, label))
            jobs.append({"mtlx": str(path), "out": str(root / f"gl_{name}_{label}.exr"), "size": SIZE, "frames": 0})
    results = render_plan({"renders": jobs})["renders"]
    out = {key: read_exr(job["out"]) for key, job in zip(keys, jobs)}
    out["results"] = dict(zip(keys, results))
    for name, (_, _, model) in materials.items():
        out[(name, "torch")] = render_scene(model, Sphere(), Camera(0.0, 0.0, 3.0, 45.0), [], res=SIZE, spp=16,
                                            texels=(8, 8), seed=1)
    return out


@pytest.fixture(scope="module")
def gl_context():
    if gl_reason() is not None:
        pytest.skip(f"no GL context for MaterialX's renderer: {gl_reason()}")


def flip(reference: np.ndarray, test: np.ndarray) -> float:
    return float(hdr_flip(reference[..., :3], test[..., :3])[1])


def inside(covered: np.ndarray, margin: float = 0.85) -> np.ndarray:
    """``covered`` pixels within ``margin`` of the sphere's radius (estimated from their count) of the centre."""
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    radius = np.sqrt(covered.sum() / np.pi)
    return covered & (np.hypot(x - SIZE / 2, y - SIZE / 2) < margin * radius)


def test_emission_renders_as_the_original(renders):
    """No light: the neural document shows its emission, at the original's colours."""
    gl, original, ours = renders[("glow", "neural")], renders[("glow", "original")], renders[("glow", "torch")]
    error = flip(original, gl)
    print(f"HDR FLIP emissive: neural vs original document {error:.4f}", file=sys.stderr)
    assert error <= 0.05
    assert renders["results"][("glow", "neural")]["covered"] > 0.5 * SIZE * SIZE * 0.3
    # Where every torch sample of a pixel reads one texel colour, MaterialX's pixel is that colour: each of
    # the four (a swapped half or a flipped v would put them elsewhere). Not near the silhouette, where the
    # viewer's MIP selection (the longer axis of a grazing footprint) mixes the colours in coarse levels.
    covered = inside(gl[..., 3] == 1)
    for colour in (ORANGE, BLUE, ORANGE / 2, BLUE / 2):
        pure = np.all(np.abs(ours - colour) < 1e-6, -1) & covered
        assert pure.sum() >= 20, colour
        np.testing.assert_allclose(gl[pure][:, :3], np.broadcast_to(colour, (pure.sum(), 3)), rtol=1e-5)


def test_cutout_shows_the_background(renders):
    """The cut-out's empty part shows the background (GlslRenderer's clear colour; RGB 0, alpha 0 in the
    written image) where the sphere is, as in the original's render; the rest is at the emission colour."""
    gl, original, ours = renders[("cut", "neural")], renders[("cut", "original")], renders[("cut", "torch")]
    result = renders["results"][("cut", "neural")]
    assert result["transparent"]
    error = flip(original, gl)
    print(f"HDR FLIP cut-out: neural vs original document {error:.4f}; covered {result['covered']} of the "
          f"sphere's {renders['results'][('glow', 'neural')]['covered']} pixels", file=sys.stderr)
    assert error <= 0.05
    sphere = renders[("glow", "neural")][..., 3] == 1  # the same sphere, opaque
    cut_away = sphere & (gl[..., 3] == 0)
    assert cut_away.sum() > 0.3 * sphere.sum()  # the right half and the bottom cap
    assert np.all(gl[cut_away][:, :3] == 0)
    # Pixel by pixel against the torch renderer of the converted model: all 16 samples on the surface -> covered at
    # the emission colour; all 16 through the cut-out or past the sphere -> the background.
    full = np.all(np.abs(ours - np.array(GLOW)) < 1e-6, -1)
    empty = np.all(ours == 0, -1)
    assert full.sum() > 300 and (empty & sphere).sum() > 300
    assert np.all(gl[full][:, 3] == 1)
    np.testing.assert_allclose(gl[full][:, :3], np.broadcast_to(GLOW, (full.sum(), 3)), rtol=1e-5)
    assert (gl[empty][:, 3] == 0).mean() >= 0.995  # a silhouette pixel or two: a tessellated sphere
    # The covered part is the left (u < 0.5) above the bottom cap (v > 0.25), image rows from the top (a
    # stray pixel at the silhouette: the tessellated sphere's inside).
    rows, cols = np.nonzero(gl[..., 3] == 1)
    assert (cols <= SIZE // 2).mean() > 0.99
    assert np.nonzero(sphere)[0].max() - np.quantile(rows, 0.99) >= 4
    assert np.all(original[..., 3] == gl[..., 3])
