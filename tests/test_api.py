"""The public API on the bundled sample stage and on stages built in memory (needs no ../shared)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import random_dirs, write_float_image
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

import mtlx2neural as m2n
from mtlx2neural.errors import InputError
from mtlx2neural.pipeline.layout import SNAPSHOT_NAME
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.pipeline.source_hash import source_hash
from mtlx2neural.scene import find_material, load_asset
from mtlx2neural.train.config import preset

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "layered_spheres.usda"


@pytest.fixture(scope="module")
def carpaint():
    return m2n.load_reference(SAMPLE, material="/World/Looks/CarPaint")


def test_shapes_and_conventions(carpaint):
    wi, wo = random_dirs(1000, seed=1), random_dirs(1000, seed=2)
    f = carpaint.eval(wi, wo)
    assert f.shape == (1000, 3) and f.dtype == torch.float32 and bool((f >= 0).all())
    # Below the horizon the cosine-weighted BRDF is exactly zero.
    assert bool((carpaint.eval(wi, -wo) == 0).all())
    assert carpaint.pdf(wi, wo).shape == (1000,)
    assert carpaint.albedo(wi[:4], samples=64).shape == (4, 3)


def test_sample_with_three_random_numbers(carpaint):
    wi = random_dirs(2048, seed=3)
    u = torch.rand(2048, 3, generator=torch.Generator().manual_seed(5))
    wo, weight, pdf = carpaint.sample(wi, u)
    ok = pdf > 1e-6
    # weight and eval/pdf are the same float32 maths evaluated in separate calls.
    torch.testing.assert_close(weight[ok], carpaint.eval(wi, wo)[ok] / pdf[ok, None], rtol=1e-5, atol=1e-6)
    assert bool(torch.isfinite(wo).all())


def test_describe_reports_layering(carpaint):
    info = carpaint.describe()
    kept = [k["closure"] for k in info["lobes_kept"]]
    assert kept == ["dielectric_bsdf", "conductor_bsdf", "dielectric_bsdf", "oren_nayar_diffuse_bsdf"]
    assert info["material"] == "/World/Looks/CarPaint"
    assert not info["textures"]


def test_sample_materials_conserve_energy_at_normal_incidence():
    # 4096 Sobol samples estimate these smooth albedos to ~1e-3; both are well below 1.
    paint = m2n.load_reference(SAMPLE, material="/World/Looks/CarPaint")
    plastic = m2n.load_reference(SAMPLE, material="Plastic")  # by prim name
    wi = torch.tensor([[0.0, 0.0, 1.0]])
    a_paint, a_plastic = paint.albedo(wi, samples=4096), plastic.albedo(wi, samples=4096)
    assert bool((a_paint <= 1.0 + 1e-3).all()) and bool((a_plastic <= 1.0 + 1e-3).all())


def test_unknown_or_skipped_material_errors():
    with pytest.raises(InputError, match="Nope"):
        m2n.load_reference(SAMPLE, material="Nope")
    # A skipped material can still be loaded when named explicitly.
    hidden = m2n.load_reference(SAMPLE, material="/World/Looks/Hidden")
    assert hidden.describe()["lobes_kept"]


# ---------------------------------------------------------------------------
# m2n.convert: an open Usd.Stage (a DCC's scene, unsaved edits included) as input

TINY = preset("fast", iterations=20, batch=256)  # decisions and files, not fidelity (as test_jobs.TINY)
PAINT, UNUSED = "/World/Looks/Paint", "/World/Looks/Unused"


def _standard_surface(stage: Usd.Stage, path: str, base: float, texture: str | None = None) -> UsdShade.Material:
    """A Material whose surface is a MaterialX standard_surface; ``texture`` (an absolute path) drives
    base_color through an ``image`` node."""
    mat = UsdShade.Material.Define(stage, path)
    sr = UsdShade.Shader.Define(stage, f"{path}/SR")
    sr.CreateIdAttr("ND_standard_surface_surfaceshader")
    sr.CreateInput("base", Sdf.ValueTypeNames.Float).Set(base)
    sr.CreateInput("specular_roughness", Sdf.ValueTypeNames.Float).Set(0.4)
    color = sr.CreateInput("base_color", Sdf.ValueTypeNames.Color3f)
    if texture is None:
        color.Set(Gf.Vec3f(0.2, 0.5, 0.8))
    else:
        img = UsdShade.Shader.Define(stage, f"{path}/Grain")
        img.CreateIdAttr("ND_image_color3")
        img.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
        color.ConnectToSource(img.CreateOutput("out", Sdf.ValueTypeNames.Color3f))
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(sr.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    return mat


def _scene(stage: Usd.Stage, texture: str | None = None) -> Usd.Stage:
    """A sphere bound to PAINT (base 0.8), and UNUSED, bound to nothing."""
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    UsdShade.MaterialBindingAPI.Apply(ball.GetPrim()).Bind(_standard_surface(stage, PAINT, 0.8, texture))
    _standard_surface(stage, UNUSED, 0.5)
    return stage


def _texture(folder: Path) -> str:
    folder.mkdir(parents=True, exist_ok=True)
    img = np.random.default_rng(7).random((4, 4, 3)).astype(np.float32)
    write_float_image(folder / "grain.exr", img)
    return str(folder / "grain.exr")


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _session_base(stage: Usd.Stage, value: float) -> None:
    """An unsaved session-layer opinion on PAINT's base weight."""
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        stage.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").Set(value)


def test_convert_an_in_memory_stage(tmp_path, monkeypatch):
    texture = _texture(tmp_path / "textures")  # absolute asset path, outside the output folder
    stage = _scene(Usd.Stage.CreateInMemory(), texture)
    _session_base(stage, 0.3)  # what must be baked: the session layer's value, not the root's 0.8
    root_before, session_before = stage.GetRootLayer().ExportToString(), stage.GetSessionLayer().ExportToString()
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    before = _files(tmp_path)

    # flagged="neural": a tiny training fails the quality gate; the test reads the neural variant it authors
    result = m2n.convert(stage, ConvertOptions(out=str(tmp_path / "out"), train=TINY, device="cpu", flagged="neural",
                                               progress=False, workers=1))

    out, layer_path, snapshot = tmp_path / "out", tmp_path / "out.usda", tmp_path / "out" / SNAPSHOT_NAME
    assert result.folder == out and result.layer_path == layer_path
    # Nothing outside the output folder and the layer was written or changed, the stage included.
    after = _files(tmp_path)
    new = sorted(set(after) - set(before))
    assert all(n.startswith("out/") or n == "out.usda" for n in new), new
    assert "out.usda" in new and f"out/{SNAPSHOT_NAME}" in new
    assert {k: after[k] for k in before} == before and not any((tmp_path / "cwd").iterdir())
    assert stage.GetRootLayer().ExportToString() == root_before
    assert stage.GetSessionLayer().ExportToString() == session_before

    # The layer: opened from the file, sublayering the snapshot, neural variant on the Material.
    assert result.layer.realPath == str(layer_path)
    assert result.layer.ComputeAbsolutePath(result.layer.subLayerPaths[0]) == str(snapshot)
    composed = Usd.Stage.Open(result.layer)
    prim = composed.GetPrimAtPath(PAINT)
    # (the authored list: USD's registry may predate mtlx2neural's schema plugin in this process)
    assert "NeuralMaterialAPI" in prim.GetMetadata("apiSchemas").GetAddedOrExplicitItems()
    vset = prim.GetVariantSets().GetVariantSet("neuralMaterial")
    assert vset.GetVariantSelection() == "neural" and set(vset.GetVariantNames()) == {"neural", "original"}
    assert composed.GetPrimAtPath("/World/Ball")  # the geometry comes from the snapshot

    # Summaries: the bound material, its source the snapshot; the unbound one skipped.
    (summary,) = result.summaries
    assert summary.material == PAINT and summary.source == str(snapshot) and summary.usd == str(layer_path)
    assert result.skipped == [{"material": UNUSED, "reason": "not bound to any renderable prim"}]

    # The snapshot holds the composed scene: the session edit, the texture's absolute path; a
    # material read back from it (as report and render do) has the source hash that was trained.
    flat = Sdf.Layer.FindOrOpen(str(snapshot))
    assert flat.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").default == pytest.approx(0.3)
    assert flat.GetAttributeAtPath(f"{PAINT}/Grain.inputs:file").default.path == texture
    again = find_material(snapshot, PAINT)
    assert source_hash(again, TINY) == summary.source_hash
    # ... and that hash is the session edit's: without it, the material hashes differently.
    stage.GetSessionLayer().Clear()
    assert source_hash(find_material(stage, PAINT), TINY) != summary.source_hash

    neural = m2n.load_neural(layer_path, PAINT)
    wi, wo = random_dirs(64, seed=11), random_dirs(64, seed=12)
    f = neural.eval(wi, wo)
    assert f.shape == (64, 3) and bool(torch.isfinite(f).all())


def test_in_memory_stage_needs_an_output_folder(tmp_path, monkeypatch):
    stage = _scene(Usd.Stage.CreateInMemory())
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="in memory.*give an output folder"):
        m2n.convert(stage, ConvertOptions(train=TINY, device="cpu", progress=False))
    assert not any(tmp_path.iterdir())


def test_a_path_and_its_open_stage_give_the_same_source_hash(tmp_path):
    asset = tmp_path / "scene.usda"
    built = _scene(Usd.Stage.CreateInMemory(), _texture(tmp_path / "textures"))
    built.GetRootLayer().Export(str(asset))
    opened = Usd.Stage.Open(str(asset))
    from_path, from_stage = find_material(asset, PAINT), find_material(opened, PAINT)
    assert from_stage.source_file == from_path.source_file == str(asset)
    assert source_hash(from_stage, TINY) == source_hash(from_path, TINY)
    assert load_asset(opened).skipped == load_asset(asset).skipped
