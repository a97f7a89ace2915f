"""The project's own samples: the textured sample generator and a short conversion of it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.cli import main
from mtlx2neural.scene import load_asset

SAMPLES = Path(__file__).resolve().parents[1] / "samples"


def _generator():
    spec = importlib.util.spec_from_file_location("make_textured_sample", SAMPLES / "make_textured_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_textured_sample_is_layered_textured_and_trainable(tmp_path, capsys):
    stage = _generator().build(tmp_path / "textured", res=64)
    scene = load_asset(stage)
    assert sorted(m.name for m in scene.materials) == ["/World/Looks/BrushedMetal", "/World/Looks/GlazedCeramic"]
    ceramic = m2n.load_reference(stage, "GlazedCeramic")
    info = ceramic.describe()
    kept = [k["closure"] for k in info["lobes_kept"]]
    assert kept[0] == "dielectric_bsdf" and "oren_nayar_diffuse_bsdf" in kept  # coat over a textured base
    assert {Path(t["file"]).name for t in info["textures"]} == {"ceramic_albedo.png", "ceramic_normal.png"}
    # The albedo varies over UV like the tile palette does.
    up = torch.tensor([[0.0, 0.0, 1.0]]).expand(256, 3)
    f = ceramic.eval(up, up, torch.rand(256, 2, generator=torch.Generator().manual_seed(0)))
    assert float(f.std(0).max()) > 1e-3
    code = main([str(stage), "--iterations", "10", "--batch", "256", "--quiet", "--device", "cpu",
                 "-o", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().err
    for name in ("World.Looks.GlazedCeramic", "World.Looks.BrushedMetal"):
        summary = json.loads((tmp_path / "out" / name / "summary.json").read_text())
        assert summary["steps"] == 10 and summary["varying_channels"] > 0


def test_rotated_sample_is_a_textured_rotation_that_the_stack_keeps(tmp_path):
    """samples/make_rotated_sample.py: the bundled files are what it writes (small), and the metal's
    specular_rotation texture reaches the lobe's tangent at level 0 of the parameter stack."""
    import math

    import numpy as np

    from mtlx2neural.textures.parameter_stack import build_parameter_stack

    spec = importlib.util.spec_from_file_location("make_rotated_sample", SAMPLES / "make_rotated_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stage = mod.build(tmp_path / "rotated")
    for name in ("spun_metal.usda", "spun_rotation.png"):  # the committed copies are the generator's output
        assert (stage.parent / name).read_bytes() == (SAMPLES / "rotated" / name).read_bytes(), name
    assert (SAMPLES / "rotated" / "spun_rotation.png").stat().st_size < 4096
    ref = m2n.load_reference(stage, "SpunMetal")
    assert {Path(t["file"]).name for t in ref.describe()["textures"]} == {"spun_rotation.png"}
    stack = build_parameter_stack(ref.compiled)
    assert stack.resolution == (16, 16) and len(stack.lean_groups) == 1
    tangent = next(v for k, v in stack.texel_values(0).items() if k.endswith(".tangent")).numpy()
    got = np.degrees(np.arctan2(tangent[:, 1], tangent[:, 0]))
    want = -360.0 * mod.rotation_map(16).reshape(-1)  # clockwise (MaterialX's rotate3d)
    diff = (got - want) % 180.0
    # 16-bit texture: the rotation is quantised to 360 / 65535 degrees; float32 maths: 0.01 degrees.
    assert np.minimum(diff, 180.0 - diff).max() < 0.01
    assert math.isclose(float(np.ptp(np.degrees(np.arctan2(tangent[:, 1], tangent[:, 0])) % 180.0)), 180.0,
                        abs_tol=10.0)  # the circles' tangents take every direction


def test_udim_sample_is_the_generators_and_its_mesh_touches_three_of_four_tiles(tmp_path):
    """samples/make_udim_sample.py: the bundled files are what it writes (small), the material reads a
    <UDIM> set of four tiles, and the mesh's UVs overlap 1001, 1002 and 1011 only (the tiles a
    conversion trains; tests/pipeline/test_udim_pipeline.py converts it)."""
    from mtlx2neural.train.udim import tiles_on_disk, training_tiles

    spec = importlib.util.spec_from_file_location("make_udim_sample", SAMPLES / "make_udim_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stage = mod.build(tmp_path / "udim")
    names = ["udim_tiles.usda"] + [f"base.{t}.png" for t in (*mod.TRAINED, mod.UNTOUCHED)]
    for name in names:  # the committed copies are the generator's output
        assert (stage.parent / name).read_bytes() == (SAMPLES / "udim" / name).read_bytes(), name
    assert sum((SAMPLES / "udim" / n).stat().st_size for n in names) < 8192
    ref = m2n.load_reference(stage, "UdimTiles")
    assert tiles_on_disk(ref.compiled) == [1001, 1002, 1011, 1012]
    tiles, _ = training_tiles(ref.compiled, str(stage), [mod.MESH])
    assert tiles == list(mod.TRAINED)
    # inspect says which tiles a conversion trains
    from mtlx2neural.pipeline.inspection import format_report, inspect_asset

    report = inspect_asset(stage)
    assert report["materials"][0]["udim_tiles"] == list(mod.TRAINED)
    assert "UDIM tiles trained: 1001, 1002, 1011" in format_report(report)


def test_mirror_sample_is_the_generators_near_mirror_textured_metal(tmp_path):
    """samples/make_mirror_sample.py: the bundled files are what it writes, and its PolishedMetal is a
    metal (one conductor lobe) whose roughness texture spans 0.02-0.3, mostly polished (median <= 0.1),
    with a normal map."""
    import numpy as np
    import OpenImageIO as oiio

    spec = importlib.util.spec_from_file_location("make_mirror_sample", SAMPLES / "make_mirror_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stage = mod.build(tmp_path / "mirror")
    for name in ("polished_metal.usda", "polished_roughness.png", "polished_normal.png"):
        assert (stage.parent / name).read_bytes() == (SAMPLES / "mirror" / name).read_bytes(), name
    ref = m2n.load_reference(stage, "PolishedMetal")
    info = ref.describe()
    assert [k["closure"] for k in info["lobes_kept"]] == ["conductor_bsdf"]
    assert {Path(t["file"]).name for t in info["textures"]} == {"polished_roughness.png", "polished_normal.png"}
    rough = oiio.ImageBuf(str(SAMPLES / "mirror" / "polished_roughness.png")).get_pixels(oiio.FLOAT)
    # 8-bit texture: the range's ends within one code value
    assert abs(float(rough.min()) - 0.02) < 1 / 255 and abs(float(rough.max()) - 0.3) < 1 / 255
    assert float(np.median(rough)) <= 0.1


def test_scene_sample_has_an_emitter_a_cut_out_and_a_near_mirror(tmp_path):
    """samples/make_scene_sample.py: the bundled files are what it writes (byte for byte), and its three
    UsdPreviewSurface materials are what the scene issue needs: Lava emits from a texture, Leaf is a
    cut-out (opacity from the texture's alpha with a threshold) about a third covered, Gold is one
    conductor lobe."""
    import torch

    from mtlx2neural.textures.surface_maps import build_surface_maps

    spec = importlib.util.spec_from_file_location("make_scene_sample", SAMPLES / "make_scene_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stage = mod.build(tmp_path / "scene")
    for name in ("glow_and_leaves.usda", "lava_rock.png", "leaf_rgba.png", "gold_roughness.png"):
        assert (stage.parent / name).read_bytes() == (SAMPLES / "scene" / name).read_bytes(), name
    import OpenImageIO as oiio  # the EXR's header carries a write time: compare its pixels

    def pixels(path):
        return oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)

    assert (pixels(stage.parent / "lava_glow.exr") == pixels(SAMPLES / "scene" / "lava_glow.exr")).all()
    lava = m2n.load_reference(SAMPLES / "scene" / "glow_and_leaves.usda", "/World/Looks/Lava")
    assert lava.describe()["surface"]["emission"] == "textured"
    assert float(lava.emission(torch.rand(256, 2, generator=torch.Generator().manual_seed(0))).max()) > 1.0
    leaf = m2n.load_reference(SAMPLES / "scene" / "glow_and_leaves.usda", "/World/Looks/Leaf")
    maps = build_surface_maps(leaf.compiled, (32, 32))
    assert maps.alpha_mode == "mask" and 0.2 < maps.coverage < 0.45
    gold = m2n.load_reference(SAMPLES / "scene" / "glow_and_leaves.usda", "/World/Looks/Gold")
    assert [k["closure"] for k in gold.describe()["lobes_kept"]] == ["conductor_bsdf"]
