"""The scene view of ``mtlx2neural report``: the whole stage, reference / neural / preview, its table and totals.

Fast tests check the memory conventions on files written here (every stored MIP level of an EXR, a DDS's
blocks, a source texture's decoded texels plus a third), the grey stand-in and the note of a ``.mtlx`` layer.
The slow ones convert a three-quad stage (a textured and a constant UsdPreviewSurface, and one whose texture
is missing, which the conversion skips) with a few training steps and check the images (the skipped quad's
pixels are the same in all three renders, the converted quads' are not), the table's statuses and the
totals against the files.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from mtlx2neural.contract import Material
from mtlx2neural.export.latents import write_mip_chain
from mtlx2neural.formats.dds import level_bytes, write_dds
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.report.html_report import scene_section, write_report
from mtlx2neural.report.scene_view import (
    GreyStandIn,
    image_memory,
    scene_view,
    shipped_bytes,
    texture_bytes,
)

CHECKER = (8, 8, 3)
"""The red checker texture: 8x8 RGB, 8 bits per channel."""


def _write_image(path: Path, img: np.ndarray, fmt: str) -> None:
    import OpenImageIO as oiio  # Local: only these tests write images

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], fmt))
    out.write_image(img)
    out.close()


# ----------------------------------------------------------------------------- fast: conventions


def test_texture_bytes_are_decoded_texels_plus_a_third(tmp_path):
    _write_image(tmp_path / "a.png", np.zeros((6, 10, 3), np.uint8), "uint8")
    _write_image(tmp_path / "b.png", np.zeros((4, 4, 4), np.uint16), "uint16")
    _write_image(tmp_path / "c.exr", np.zeros((3, 5, 1), np.float32), "float")
    _write_image(tmp_path / "d.exr", np.zeros((8, 8, 3), np.float32), "half")
    assert texture_bytes(tmp_path / "a.png") == 10 * 6 * 3 * 1 * 4 // 3
    assert texture_bytes(tmp_path / "b.png") == 4 * 4 * 4 * 2 * 4 // 3
    assert texture_bytes(tmp_path / "c.exr") == 5 * 3 * 1 * 4 * 4 // 3
    assert texture_bytes(tmp_path / "d.exr") == 8 * 8 * 3 * 2 * 4 // 3
    (tmp_path / "e.txt").write_text("not an image")
    assert texture_bytes(tmp_path / "e.txt") is None


def test_shipped_bytes_count_every_level_and_the_weights(tmp_path):
    export = tmp_path / "neural"
    export.mkdir()
    levels = [np.zeros((16 >> j, 8 >> j if j < 4 else 1, 4), np.float16) for j in range(5)]  # 16x8 .. 1x1
    write_mip_chain(export / "latents_0.exr", levels)
    write_mip_chain(export / "opacity.exr", [lv[..., :1].copy() for lv in levels])
    blobs = [bytes(level_bytes(71, 8, 8, j)) for j in range(4)]  # BC1, 8x8 down to 1x1
    write_dds(export / "latents_1.dds", blobs, 8, 8, 71)
    (export / "weights.bin").write_bytes(bytes(1234))
    (export / "weights.json").write_text("{}")  # not loaded as memory: not counted
    s = shipped_bytes(export)
    texels = sum(lv.shape[0] * lv.shape[1] for lv in levels)
    assert s["latent"] == texels * 4 * 2 + sum(map(len, blobs)) == image_memory(export / "latents_0.exr") + 32 + 24
    assert s["surface"] == texels * 1 * 2
    assert s["weights"] == 1234
    assert s["memory"] == s["latent"] + s["weights"] + s["surface"]
    assert s["disk"] == sum((export / n).stat().st_size for n in ("latents_0.exr", "latents_1.dds", "opacity.exr",
                                                                 "weights.bin"))
    assert sorted(s["files"]) == ["latents_0.exr", "latents_1.dds", "opacity.exr", "weights.bin"]


def test_grey_stand_in_keeps_the_contract():
    g = GreyStandIn()
    assert isinstance(g, Material)
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.3, 0.0, 0.954], [0.0, 0.0, -1.0]])
    wo, weight, pdf = g.sample(wi, torch.tensor([[0.2, 0.7], [0.9, 0.1], [0.5, 0.5]]))
    assert torch.allclose(pdf, g.pdf(wi, wo))
    ok = pdf > 0
    assert ok[:2].all() and not ok[2]
    assert torch.allclose(weight[ok], g.eval(wi, wo)[ok] / pdf[ok, None])
    assert torch.allclose(g.albedo(wi[:1]), torch.full((1, 3), GreyStandIn.ALBEDO), atol=1e-3)


def test_a_mtlx_layer_gets_a_note_instead(tmp_path):
    layer = tmp_path / "mat_neural.usda"
    layer.write_text('#usda 1.0\n(\n    customLayerData = {\n        dictionary mtlx2neural = {\n'
                     '            string source = "./mat.mtlx"\n        }\n    }\n)\n')
    why = scene_view(layer)
    assert isinstance(why, str) and "MaterialX document" in why
    html, numbers = scene_section(layer, tmp_path, 16, 1, 0)
    assert html.startswith('<p class="note">No scene view') and html.count("\n") == 0 and numbers == why
    assert not list(tmp_path.glob("scene_*.png"))


# ----------------------------------------------------------------------------- slow: a converted scene


def build_stage(folder: Path) -> Path:
    """Three quads in a row facing the camera: Red (an 8x8 checker texture), Blue (constant), Broken (a
    texture that does not exist, so the conversion skips it); a camera and a distant light."""
    checker = (np.indices(CHECKER[:2]).sum(0) % 2)[..., None] * np.array([200, 40, 30]) + np.array([40, 10, 10])
    _write_image(folder / "red_checker.png", checker.astype(np.uint8), "uint8")
    stage = Usd.Stage.CreateNew(str(folder / "three.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f

    def preview(name):
        mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        mat.CreateSurfaceOutput().ConnectToSource(sh.CreateOutput("surface", Sdf.ValueTypeNames.Token))
        sh.CreateInput("roughness", f).Set(0.5)
        return mat, sh

    def texture(name, file):
        base = f"/World/Looks/{name}"
        st = UsdShade.Shader.Define(stage, f"{base}/st")
        st.CreateIdAttr("UsdPrimvarReader_float2")
        st.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
        tex = UsdShade.Shader.Define(stage, f"{base}/tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{file}"))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
            st.CreateOutput("result", Sdf.ValueTypeNames.Float2))
        return tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)

    def quad(name, mat, x0):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Geo/{name}")
        mesh.CreatePointsAttr([(x0, -0.6, 0), (x0 + 1.2, -0.6, 0), (x0 + 1.2, 0.6, 0), (x0, 0.6, 0)])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying)
        st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)

    red, sh = preview("Red")
    sh.CreateInput("diffuseColor", c3).ConnectToSource(texture("Red", "red_checker.png"))
    blue, sh = preview("Blue")
    sh.CreateInput("diffuseColor", c3).Set(Gf.Vec3f(0.1, 0.2, 0.8))
    broken, sh = preview("Broken")
    sh.CreateInput("diffuseColor", c3).ConnectToSource(texture("Broken", "missing.png"))
    quad("RedQuad", red, -2.0)
    quad("BlueQuad", blue, -0.6)
    quad("BrokenQuad", broken, 0.8)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 5.0))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-20.0, 20.0, 0.0))
    stage.GetRootLayer().Save()
    return folder / "three.usda"


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    # Local: the conversion modules (torch training) matter only for the slow tests.
    from mtlx2neural.pipeline.convert import convert_asset
    from mtlx2neural.pipeline.options import ConvertOptions

    # Local: as above.
    from mtlx2neural.train.config import preset

    d = tmp_path_factory.mktemp("scene")
    asset = build_stage(d)
    records = convert_asset(asset, ConvertOptions(out=str(d / "out"),
                                                  train=preset("fast", iterations=10, batch=128, probe_every=0,
                                                               preview_iterations=2),
                                                  progress=False, device="cpu", workers=1))
    layer = Path(records[0].usd)
    return d, layer, {r.material: r for r in records}


@pytest.fixture(scope="module")
def view(converted):
    _, layer, _ = converted
    return scene_view(layer, res=48, spp=2, seed=0)


def _interior(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 3x3 neighbourhood is all in ``mask`` (so every jittered sample of them hits it)."""
    m = np.pad(mask, 1)
    out = np.ones_like(mask)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            out &= m[dy:dy + mask.shape[0], dx:dx + mask.shape[1]]
    return out


@pytest.mark.slow
def test_every_material_is_listed_with_its_status(converted, view):
    _, _, records = converted
    by_prim = {e.prim: e for e in view.entries}
    assert set(by_prim) == {"/World/Looks/Red", "/World/Looks/Blue", "/World/Looks/Broken"}
    broken = by_prim["/World/Looks/Broken"]
    assert broken.status == "skipped" and "missing.png" in broken.reason and broken.record is None
    assert "reference in all three" in broken.drawn and broken.bound_prims == ["/World/Geo/BrokenQuad"]
    for prim in ("/World/Looks/Red", "/World/Looks/Blue"):
        e, r = by_prim[prim], records[prim]
        assert e.status == ("flagged" if r.quality["flagged"] else "converted")
        assert e.record.flip_mean == r.flip_mean and e.texels == tuple(r.resolution)
    assert view.totals["converted"] == 2 and view.totals["skipped"] == 1
    assert view.totals["train_seconds"] == round(sum(r.train_seconds for r in records.values()), 2)


@pytest.mark.slow
def test_images_differ_exactly_where_a_material_differs(view):
    imgs = view.images
    assert all(imgs[k].shape == (48, 48, 3) and np.isfinite(imgs[k]).all() for k in imgs)
    index = {e.prim: i for i, e in enumerate(view.entries)}
    for prim, i in index.items():
        inside = _interior(view.ids == i)
        assert inside.sum() >= 20, prim  # each quad is drawn
        for kind in ("neural", "preview"):
            diff = np.abs(imgs[kind] - imgs["reference"])[inside]
            # Broken: its reference in all three, same random numbers. Every quad's fallback is its own
            # UsdPreviewSurface (nothing fitted): the reference in the preview image.
            if prim == "/World/Looks/Broken" or kind == "preview":
                assert diff.max() == 0.0, (prim, kind)
            else:  # ten training steps: visibly not the reference
                assert diff.max() > 1e-3, (prim, kind)
    assert (imgs["reference"][_interior(view.ids == -1)] == 0).all()  # the background is black
    assert 0.0 < view.flip["neural"] < 1.0 and view.flip["preview"] == 0.0
    own = [e for e in view.entries if e.status != "skipped"]
    assert own and all(e.record.preview.get("own") for e in own)


@pytest.mark.slow
def test_memory_totals_match_the_files(converted, view):
    d, _, _ = converted
    shipped = {"memory": 0, "disk": 0}
    for e in view.entries:
        if e.status == "skipped":
            assert e.shipped is None
            continue
        export = e.folder / "neural"
        exrs = sorted(export.glob("latents_*.exr"))
        assert len(exrs) == 2  # 8 latent channels, 4 per EXR
        latent = sum(lv.size * 2 for p in exrs for lv in read_mip_chain(p))  # half: 2 bytes, every level
        weights = (export / "weights.bin").stat().st_size
        assert (e.shipped["latent"], e.shipped["weights"], e.shipped["surface"]) == (latent, weights, 0)
        shipped["memory"] += latent + weights
        shipped["disk"] += sum(p.stat().st_size for p in exrs) + weights
    t = view.totals
    assert (t["shipped_memory"], t["shipped_disk"]) == (shipped["memory"], shipped["disk"])
    # the one source texture a converted material reads: 8x8 RGB, 1 byte per channel, plus a third
    assert t["source_textures"] == math.prod(CHECKER) * 4 // 3 and t["source_files"] == 1
    assert t["ratio"] == round(shipped["memory"] / t["source_textures"], 4)
    by_prim = {e.prim: e for e in view.entries}
    assert list(by_prim["/World/Looks/Red"].textures) == [str((d / "red_checker.png").resolve())]
    assert by_prim["/World/Looks/Blue"].textures == {}


@pytest.mark.slow
def test_the_report_starts_with_the_scene(converted, tmp_path):
    _, layer, _ = converted
    out = tmp_path / "rep"
    r = write_report(layer, out, analytic_iterations=2, res=8, spp=1, scene_res=32, scene_spp=1,
                     materials=["Blue"])
    page = (out / "index.html").read_text()
    assert page.index('id="scene"') < page.index('id="material-0"')
    section = page[page.index('id="scene"'):page.index('id="material-0"')]
    for name in ("reference", "neural", "preview", "neural_flip", "preview_flip"):
        assert f'src="scene_{name}.png"' in section
        assert (out / f"scene_{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = re.findall(r"<tr><td class=\"l\">(/World/Looks/\w+)<br>.*?</td><td class=\"l status-(\w+)\">", section)
    assert sorted(rows) == sorted((e["material"], e["status"]) for e in r["scene"]["materials"])
    assert ("/World/Looks/Broken", "skipped") in rows and "skipped by the conversion" in section
    assert json.loads((out / "scene.json").read_text())["totals"] == r["scene"]["totals"]
