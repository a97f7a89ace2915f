"""Emission and opacity in every USD consumer of the neural layer: the NeuralMaterialAPI's attributes, the
MaterialX network (``usd_mtlx_network``), the UsdPreviewSurface fallback (``author_preview_surface``),
USD's validators and Blender's USD importer.

No training: the layer is written for hand-made exports of the sample scene
``samples/scene/glow_and_leaves.usda`` (whose Materials connect ``outputs:surface`` themselves, so the
layer routes it through the ``NeuralSwitch``): Lava emits (an 8x8 emission map, or a constant), Leaf is a
cut-out (an 8x8 mask, or a constant blend opacity), Gold neither. Its preview textures are an untrained
analytic baseline's, its emission and opacity files :func:`write_surface_files`'s.

Blender: ``bpy`` (Blender as a Python module) runs in a child process, which imports the layer with
``bpy.ops.wm.usd_import`` and reports the imported materials' Principled BSDF. It needs a Python with bpy:
this interpreter when it has it, else ``MTLX2NEURAL_BPY_PYTHON``; otherwise the test skips.
``pip install bpy==4.2.23`` (Blender 4.2 LTS, Python 3.11) keeps numpy 2; bpy 5.0 requires numpy < 2, so it
needs a virtual environment of its own (named by ``MTLX2NEURAL_BPY_PYTHON``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from usd_validation import VALIDATE  # noqa: E402  (USD's validators in a fresh process)

from mtlx2neural.baseline.analytic_model import AnalyticMaterial, write_preview_textures
from mtlx2neural.codegen.materialx_node import node_names
from mtlx2neural.export.surface_files import write_surface_files
from mtlx2neural.export.usd_writer import ExportedMaterial, write_neural_layer
from mtlx2neural.formats.weights import architecture
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.pipeline.layout import material_folder
from mtlx2neural.textures.surface_maps import (
    SurfaceMaps,
    coverage_preserving,
    level_shapes,
)

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "samples" / "scene"
LAVA, LEAF, GOLD = "/World/Looks/Lava", "/World/Looks/Leaf", "/World/Looks/Gold"
EMISSION_CONSTANT = (3.0, 1.5, 0.25)
OPACITY_CONSTANT = 0.375
SURFACE_ATTRS = ("neural:emissionTexture", "neural:emissionColor", "neural:opacityTexture", "neural:opacity",
                 "neural:alphaMode", "neural:alphaCutoff")


def _pyramid(level0: torch.Tensor) -> list[torch.Tensor]:
    return [torch.nn.functional.adaptive_avg_pool2d(level0[None], s)[0] for s in level_shapes(*level0.shape[-2:])]


def emission_map() -> torch.Tensor:
    """[3, 8, 8]: HDR radiance, a ramp along u times a colour, brighter towards the top rows."""
    u = (torch.arange(8, dtype=torch.float32) + 0.5) / 8
    rows = torch.linspace(2.0, 0.5, 8)
    return torch.tensor([4.0, 1.0, 0.25])[:, None, None] * (rows[:, None] * u[None, :])[None]


def mask_map() -> torch.Tensor:
    """[1, 8, 8]: a cut-out disc (1 inside, 0 outside)."""
    y, x = torch.meshgrid(torch.arange(8) + 0.5, torch.arange(8) + 0.5, indexing="ij")
    return (((x - 4) ** 2 + (y - 4) ** 2) <= 9).float()[None]


def surface_maps(name: str, kind: str) -> SurfaceMaps | None:
    if name == LAVA:
        return (SurfaceMaps(emission_levels=_pyramid(emission_map())) if kind == "textured"
                else SurfaceMaps(emission_constant=EMISSION_CONSTANT))
    if name == LEAF:
        if kind == "textured":
            m = mask_map()
            return SurfaceMaps(opacity_levels=coverage_preserving(m, len(level_shapes(8, 8))), alpha_mode="mask",
                               coverage=float(m.mean()))
        return SurfaceMaps(opacity_constant=OPACITY_CONSTANT, alpha_mode="blend", coverage=OPACITY_CONSTANT)
    return None


def write_scene(folder: Path, kind: str) -> dict:
    """The sample scene copied into ``folder`` and its neural layer for hand-made exports (module docstring)."""
    shutil.copytree(SCENE, folder, dirs_exist_ok=True)
    asset = folder / "glow_and_leaves.usda"
    torch.manual_seed(0)
    arch = architecture(NeuralMaterial((1, 1), in_dim=2, latent_dim=8, frames=2, decoder="2x16"))
    preview_model = AnalyticMaterial((4, 4))
    mats, exports = [], {}
    for name in (LAVA, LEAF, GOLD):
        d = folder / "glow_and_leaves_neural" / material_folder(name) / "neural"
        manifest, _ = write_surface_files(surface_maps(name, kind), d)
        for f in ("latents_0.exr", "latents_1.exr", "weights.bin", "weights.json", "materialx/latent_atlas_0.exr",
                  "materialx/latent_atlas_1.exr"):  # stand-ins: only the layer's asset paths must resolve
            (d / f).parent.mkdir(parents=True, exist_ok=True)
            (d / f).touch()
        baked = write_preview_textures(preview_model, d / "preview")
        mats.append(ExportedMaterial(
            name, name.rsplit("/", 1)[-1], d, [d / "latents_0.exr", d / "latents_1.exr"], d / "weights.bin",
            d / "weights.json", arch, "ab" * 32,
            {"flip": 0.125, "iterations": 30, "preset": "fast", "device": "cpu (test)", "train_seconds": 1.5},
            mtlx_document=d / "materialx" / node_names(name).mtlx, preview=baked, surface=manifest))
        exports[name] = d
    usda = write_neural_layer(asset, mats, folder / "glow_and_leaves_neural.usda")
    return {"asset": asset, "usda": usda, "exports": exports, "kind": kind}


@pytest.fixture(scope="module", params=["textured", "constant"])
def scene(request, tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp(f"scene_{request.param}"), request.param)


def _stage(usda: Path, variant: str = "neural"):
    """The layer's stage with ``variant`` selected on every Material (keep it alive while its prims are used)."""
    # Local, as in the package: pxr loads USD's plugins on import; collection stays light.
    from pxr import Usd

    stage = Usd.Stage.Open(str(usda))
    for name in (LAVA, LEAF, GOLD):
        stage.GetPrimAtPath(name).GetVariantSets().GetVariantSet("neuralMaterial").SetVariantSelection(variant)
    return stage


def _material(stage, prim: str):
    # Local, as in the package: pxr loads USD's plugins on import; collection stays light.
    from pxr import UsdShade

    return UsdShade.Material(stage.GetPrimAtPath(prim))


def _source(inp):
    """(source Shader, its output name) of a connected UsdShade input; fails when it is not connected."""
    # Local, as in the package: pxr loads USD's plugins on import; collection stays light.
    from pxr import UsdShade

    assert inp and inp.HasConnectedSource(), f"{inp.GetAttr().GetPath() if inp else inp} is not connected"
    (info,) = inp.GetConnectedSources()[0]
    return UsdShade.Shader(info.source.GetPrim()), info.sourceName


def _file(shader) -> Path:
    """The resolved file of a texture reader's ``inputs:file``."""
    value = shader.GetInput("file").Get()
    assert value.resolvedPath, f"{shader.GetPath()}: {value.path} does not resolve"
    return Path(value.resolvedPath)


# ----------------------------------------------------------------------------- the NeuralMaterialAPI


def test_api_attributes_state_what_each_material_has(scene):
    lava_dir, leaf_dir = scene["exports"][LAVA], scene["exports"][LEAF]
    stage = _stage(scene["usda"])
    lava, leaf, gold = (_material(stage, name) for name in (LAVA, LEAF, GOLD))

    def authored(m):
        return {a: m.GetPrim().GetAttribute(a).Get() for a in SURFACE_ATTRS
                if m.GetPrim().GetAttribute(a).HasAuthoredValue()}

    a, b = authored(lava), authored(leaf)
    if scene["kind"] == "textured":
        assert sorted(a) == ["neural:emissionColor", "neural:emissionTexture"]
        assert a["neural:emissionTexture"].path == f"./glow_and_leaves_neural/{material_folder(LAVA)}/neural/emission.exr"
        assert Path(a["neural:emissionTexture"].resolvedPath) == lava_dir / "emission.exr"
        assert tuple(a["neural:emissionColor"]) == (1.0, 1.0, 1.0)
        assert sorted(b) == ["neural:alphaCutoff", "neural:alphaMode", "neural:opacityTexture"]
        assert Path(b["neural:opacityTexture"].resolvedPath) == leaf_dir / "opacity.exr"
        assert (b["neural:alphaMode"], b["neural:alphaCutoff"]) == ("mask", 0.5)
    else:
        assert sorted(a) == ["neural:emissionColor"]
        assert tuple(a["neural:emissionColor"]) == pytest.approx(EMISSION_CONSTANT)
        assert sorted(b) == ["neural:alphaMode", "neural:opacity"]
        assert (b["neural:alphaMode"], b["neural:opacity"]) == ("blend", OPACITY_CONSTANT)
    assert authored(gold) == {}
    original = _stage(scene["usda"], "original")
    for name in (LAVA, LEAF):  # the original variant holds none of it
        assert authored(_material(original, name)) == {}, name


# ----------------------------------------------------------------------------- the MaterialX network


def test_materialx_network_feeds_edf_and_opacity(scene):
    # Local, as in the package: pxr loads USD's plugins on import; collection stays light.
    from pxr import UsdShade

    stage = _stage(scene["usda"])

    def surface_node(name):
        shader, _, _ = _material(stage, name).ComputeSurfaceSource("mtlx")
        assert shader and shader.GetIdAttr().Get() == "ND_surface", name
        bsdf, _ = _source(shader.GetInput("bsdf"))
        texcoord, _ = _source(bsdf.GetInput("texcoord"))
        return shader, texcoord

    def image(inp, node_id, texcoord):
        img, out = _source(inp)
        assert (img.GetIdAttr().Get(), out) == (node_id, "out")
        assert _source(img.GetInput("texcoord"))[0].GetPath() == texcoord.GetPath()  # the BSDF's st reader
        assert [img.GetInput(a).Get() for a in ("uaddressmode", "vaddressmode")] == ["periodic", "periodic"]
        return img

    lava, texcoord = surface_node(LAVA)
    edf, out = _source(lava.GetInput("edf"))
    assert (edf.GetIdAttr().Get(), out, edf.GetPrim().GetName()) == ("ND_uniform_edf", "out", node_names(LAVA).edf)
    assert not lava.GetInput("opacity")
    leaf, texcoord_leaf = surface_node(LEAF)
    assert not leaf.GetInput("edf")
    if scene["kind"] == "textured":
        emission = image(edf.GetInput("color"), "ND_image_color3", texcoord)
        assert _file(emission) == scene["exports"][LAVA] / "emission.exr"
        assert emission.GetInput("file").GetAttr().GetColorSpace() == "lin_rec709"
        cut, out = _source(leaf.GetInput("opacity"))
        assert (cut.GetIdAttr().Get(), out) == ("ND_ifgreatereq_float", "out")
        assert [cut.GetInput(k).Get() for k in ("value2", "in1", "in2")] == [0.5, 1.0, 0.0]
        opacity = image(cut.GetInput("value1"), "ND_image_float", texcoord_leaf)
        assert _file(opacity) == scene["exports"][LEAF] / "opacity.exr"
    else:
        assert tuple(edf.GetInput("color").Get()) == pytest.approx(EMISSION_CONSTANT)
        assert not leaf.GetInput("opacity").HasConnectedSource()
        assert leaf.GetInput("opacity").Get() == OPACITY_CONSTANT
    gold, _ = surface_node(GOLD)
    assert not gold.GetInput("edf") and not gold.GetInput("opacity")
    ids = {UsdShade.Shader(p).GetIdAttr().Get() for p in stage.GetPrimAtPath(GOLD).GetChildren()
           if p.GetTypeName() == "Shader"}
    assert not ids & {"ND_uniform_edf", "ND_image_color3", "ND_image_float", "ND_ifgreatereq_float"}, ids


# ----------------------------------------------------------------------------- the UsdPreviewSurface fallback


def test_preview_surface_reads_emission_and_opacity(scene):
    stage = _stage(scene["usda"])

    def preview(name):
        shader, _, _ = _material(stage, name).ComputeSurfaceSource()
        assert shader and shader.GetIdAttr().Get() == "UsdPreviewSurface", name
        return shader

    def texture(inp, output):
        tex, out = _source(inp)
        assert (tex.GetIdAttr().Get(), out) == ("UsdUVTexture", output)
        assert tex.GetInput("sourceColorSpace").Get() == "raw"
        assert [tex.GetInput(a).Get() for a in ("wrapS", "wrapT")] == ["repeat", "repeat"]
        assert _source(tex.GetInput("st"))[0].GetIdAttr().Get() == "UsdPrimvarReader_float2"
        return tex

    lava, leaf, gold = preview(LAVA), preview(LEAF), preview(GOLD)
    if scene["kind"] == "textured":
        assert _file(texture(lava.GetInput("emissiveColor"), "rgb")) == scene["exports"][LAVA] / "emission.exr"
        assert _file(texture(leaf.GetInput("opacity"), "r")) == scene["exports"][LEAF] / "opacity.exr"
        assert leaf.GetInput("opacityThreshold").Get() == 0.5
    else:
        assert tuple(lava.GetInput("emissiveColor").Get()) == pytest.approx(EMISSION_CONSTANT)
        assert leaf.GetInput("opacity").Get() == OPACITY_CONSTANT
        assert leaf.GetInput("opacityThreshold").Get() == 0.0
    assert not lava.GetInput("opacity") and not lava.GetInput("opacityThreshold")
    assert not leaf.GetInput("emissiveColor")
    assert not any(gold.GetInput(k) for k in ("emissiveColor", "opacity", "opacityThreshold"))


# ----------------------------------------------------------------------------- USD's validators




def test_usd_validators_find_nothing_new(scene):
    """All registered validators, in a fresh process with the plugin: the layer adds no error to the
    input's, except the MaterialX nodedef ids that usd-core's Sdr does not know (no UsdMtlx)."""
    asset, usda = scene["asset"], scene["usda"]
    proc = subprocess.run([sys.executable, "-c", VALIDATE, str(asset), str(usda)], capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])

    def key(e):
        return (e[0], e[1]) if e[1] else (e[0], e[2].replace(str(usda), "").replace(str(asset), ""))

    old = {key(e) for e in result[str(asset)]}
    new = [e for e in result[str(usda)] if key(e) not in old
           and not (e[0] == "MissingShaderIdInRegistry" and "shaderId 'ND_" in e[2])]
    assert new == []


# ----------------------------------------------------------------------------- Blender's USD importer


BLENDER = textwrap.dedent("""
    import json, sys
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert bpy.ops.wm.usd_import(filepath=sys.argv[1]) == {"FINISHED"}

    def upstream(socket, seen=None):
        # every node feeding this socket, nearest first: (bl_idname, operation, image file, constants)
        out = []
        for link in socket.links:
            n = link.from_node
            out.append({"node": n.bl_idname, "socket": link.from_socket.name,
                        "operation": getattr(n, "operation", None),
                        "file": bpy.path.abspath(n.image.filepath) if getattr(n, "image", None) else None,
                        "colorspace": n.image.colorspace_settings.name if getattr(n, "image", None) else None,
                        "values": [round(float(i.default_value), 6) for i in n.inputs
                                   if not i.is_linked and isinstance(getattr(i, "default_value", None), float)]})
            for i in n.inputs:
                out += upstream(i)
        return out

    report = {"blender": bpy.app.version_string}
    for m in bpy.data.materials:
        bsdf = next((n for n in m.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None) \\
            if m.use_nodes else None
        if bsdf is None:
            report[m.name] = None
            continue
        entry = {"blend_method": m.blend_method, "alpha_threshold": m.alpha_threshold,
                 "surface_render_method": getattr(m, "surface_render_method", None)}
        for name in ("Emission Color", "Emission Strength", "Alpha", "Base Color"):
            s = bsdf.inputs[name]
            v = s.default_value
            entry[name] = {"value": [float(x) for x in v] if hasattr(v, "__len__") else float(v),
                           "upstream": upstream(s)}
        images = {}
        for n in m.node_tree.nodes:
            if getattr(n, "image", None) is not None:
                img = n.image
                w, h = img.size
                px = [float(x) for x in img.pixels[:]] if w * h <= 4096 else []
                images[bpy.path.abspath(img.filepath)] = {"size": [w, h], "channels": img.channels, "pixels": px}
        entry["images"] = images
        report[m.name] = entry
    print("REPORT " + json.dumps(report))
""")


def bpy_python() -> str | None:
    """A Python that can import bpy: ``MTLX2NEURAL_BPY_PYTHON``, else this interpreter; None when neither."""
    python = os.environ.get("MTLX2NEURAL_BPY_PYTHON") or sys.executable
    try:
        ok = subprocess.run([python, "-c", "import bpy"], capture_output=True, timeout=120, check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return None
    return python if ok else None


def blender_import(usda: Path) -> dict:
    """Blender's USD import of ``usda`` in a child process (no USD plugin variables: Blender's own USD
    sees the layer as a tool without this project's plugin would): material name -> its Principled BSDF."""
    python = bpy_python()
    if python is None:
        pytest.skip("bpy (Blender as a Python module) is not installed: pip install bpy==4.2.23 (Python 3.11; "
                    "keeps numpy 2), or set MTLX2NEURAL_BPY_PYTHON to a Python that has bpy")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PXR_")}
    proc = subprocess.run([python, "-c", BLENDER, str(usda)], capture_output=True, text=True, timeout=300,
                          check=False, env=env)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("REPORT ")), None)
    assert proc.returncode == 0 and line, f"Blender's import failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return json.loads(line[len("REPORT "):])


def _image_of(entry: dict, socket: str) -> dict:
    """The nearest image node feeding ``socket`` of the Principled BSDF."""
    found = [n for n in entry[socket]["upstream"] if n["file"]]
    assert found, f"{socket} is fed by no image: {entry[socket]}"
    return found[0]


def test_blender_imports_emission_and_cutout(scene):
    report = blender_import(scene["usda"])
    lava, leaf, gold = report.get("Lava"), report.get("Leaf"), report.get("Gold")
    assert lava and leaf and gold, report.keys()
    # The preview's base colour comes through (all three): the neural variant's UsdPreviewSurface is what Blender read.
    for entry, name in ((lava, LAVA), (leaf, LEAF), (gold, GOLD)):
        base = _image_of(entry, "Base Color")
        assert Path(base["file"]) == scene["exports"][name] / "preview" / "diffuseColor.exr", base
    if scene["kind"] == "textured":
        emission = _image_of(lava, "Emission Color")
        assert Path(emission["file"]) == scene["exports"][LAVA] / "emission.exr"
        assert lava["Emission Strength"]["value"] == pytest.approx(1.0)
        img = lava["images"][emission["file"]]
        assert img["size"] == [8, 8]
        # Blender's pixels: RGBA rows from the bottom; the map's row 0 is the top (v = 1)
        px = np.array(img["pixels"], dtype=np.float32).reshape(8, 8, 4)[::-1, :, :3]
        want = emission_map().permute(1, 2, 0).numpy().astype(np.float16).astype(np.float32)
        np.testing.assert_allclose(px, want, rtol=1e-3, atol=1e-4)
        alpha = _image_of(leaf, "Alpha")
        assert Path(alpha["file"]) == scene["exports"][LEAF] / "opacity.exr"
        chain = leaf["Alpha"]["upstream"]
        # outputs:r: the image's colour through a Separate Color's Red
        assert {"node": "ShaderNodeSeparateColor", "socket": "Red"}.items() <= next(
            n for n in chain if n["node"] == "ShaderNodeSeparateColor").items(), chain
        assert alpha["socket"] == "Color"
        # The alpha test at opacityThreshold 0.5: Blender 5.0 builds 1 - (alpha < 0.5) on any channel;
        # Blender 4.2 only on an image's alpha output, so there the mask is a blended fraction.
        ops = {n["operation"]: n for n in chain if n["node"] == "ShaderNodeMath"}
        if ops:
            assert set(ops) == {"LESS_THAN", "SUBTRACT"} and 0.5 in ops["LESS_THAN"]["values"], chain
        elif not report["blender"].startswith("4."):
            pytest.fail(f"Blender {report['blender']} did not alpha-test the cut-out: {chain}")
        assert leaf["surface_render_method"] in ("BLENDED", "FORWARD") or leaf["blend_method"] != "OPAQUE", leaf
        pixels = np.array(leaf["images"][alpha["file"]]["pixels"], dtype=np.float32).reshape(8, 8, -1)[::-1, :, 0]
        np.testing.assert_allclose(pixels, mask_map()[0].numpy(), atol=1e-3)
    else:
        assert not lava["Emission Color"]["upstream"]
        got = np.array(lava["Emission Color"]["value"][:3]) * lava["Emission Strength"]["value"]
        np.testing.assert_allclose(got, EMISSION_CONSTANT, rtol=1e-5)
        assert not leaf["Alpha"]["upstream"] and leaf["Alpha"]["value"] == pytest.approx(OPACITY_CONSTANT)
        assert leaf["blend_method"] != "OPAQUE"
    # nothing emits or is cut out where the material has neither
    assert gold["Emission Strength"]["value"] == 0.0 or not any(gold["Emission Color"]["value"][:3])
    assert not gold["Emission Color"]["upstream"] and not gold["Alpha"]["upstream"]
    assert gold["Alpha"]["value"] == 1.0
    assert lava["Alpha"]["value"] == 1.0 and not lava["Alpha"]["upstream"]
    assert leaf["Emission Strength"]["value"] == 0.0 or not any(leaf["Emission Color"]["value"][:3])
