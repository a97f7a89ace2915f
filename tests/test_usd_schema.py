"""The codeless NeuralMaterialAPI schema and the Sdr NeuralBSDF shader definition.

USD builds its schema and Sdr registries once per process, so most checks run
in a fresh ``python -c`` subprocess with a controlled environment; the script
asserts and the test checks its exit status. This module also registers the
plugin at import, for the in-process check (and any later test in the same
pytest process).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from mtlx2neural import usd_plugin_path, usd_schema

usd_schema.register()  # before anything else in this process builds USD's schema registry

_USD_VARS = ("PXR_PLUGINPATH_NAME", "PXR_SDR_FS_PLUGIN_SEARCH_PATHS", "PXR_SDR_FS_PLUGIN_ALLOWED_EXTS")

# name -> (Sdf type name, fallback or None)
EXPECTED_ATTRS = {
    "neural:version": ("int", 1),
    "neural:latentChannels": ("int", None),
    "neural:frameCount": ("int", None),
    "neural:decoderLayers": ("int[]", None),
    "neural:samplerLayers": ("int[]", None),
    "neural:encoderLayers": ("int[]", None),
    "neural:activation": ("token", "relu"),
    "neural:outputActivation": ("token", "exp_minus_3_cos"),
    "neural:latentTextures": ("asset[]", None),
    "neural:latentResolution": ("int2", None),
    "neural:weights": ("asset", None),
    "neural:weightsManifest": ("asset", None),
    "neural:weightsLayout": ("token", "row_major_fp16"),
    "neural:proxyType": ("token", "tilted_cosine_aniso_ggx"),
    "neural:sourceHash": ("string", None),
    "neural:metrics:flip": ("float", None),
    "neural:metrics:iterations": ("int", None),
    "neural:metrics:preset": ("token", None),
    "neural:metrics:device": ("string", None),
    "neural:metrics:trainSeconds": ("float", None),
    "neural:quality": ("token", None),
    "neural:qualityReasons": ("string[]", None),
    "neural:emissionTexture": ("asset", None),
    "neural:emissionColor": ("color3f", None),
    "neural:opacityTexture": ("asset", None),
    "neural:opacity": ("float", 1.0),
    "neural:alphaMode": ("token", "opaque"),
    "neural:alphaCutoff": ("float", 0.5),
}


def _run(script: str, *args: str, plugin_env: bool = False) -> str:
    """Run ``script`` with ``args`` in a fresh interpreter and return its stdout; the USD
    plugin variables are cleared (``plugin_env=True``: set from usd_schema.environment())."""
    env = {k: v for k, v in os.environ.items() if k not in _USD_VARS}
    if plugin_env:
        env = usd_schema.environment(env)
    env.setdefault("OMP_NUM_THREADS", "1")
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, f"subprocess failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def test_plugin_path_holds_the_plugin():
    path = usd_schema.plugin_path()
    assert usd_plugin_path() == str(path)
    for name in ("schema.usda", "generatedSchema.usda", "plugInfo.json", "shaders/NeuralBSDF.usda",
                 "shaders/neural_bsdf.slang"):
        assert (path / name).is_file(), name
    assert "@PLUG_INFO" not in (path / "plugInfo.json").read_text()


def test_generated_files_are_up_to_date(tmp_path):
    pytest.importorskip("jinja2", reason="usdGenSchema needs jinja2 (pip install mtlx2neural[test])")
    usd_schema.regenerate(tmp_path)
    for name in ("generatedSchema.usda", "plugInfo.json"):
        committed = (usd_schema.plugin_path() / name).read_text()
        assert (tmp_path / name).read_text() == committed, (
            f"schemas/{name} is stale: run python -m mtlx2neural.usd_schema")


def test_schema_in_this_process():
    """Registered at import of this module, before pytest ran any test."""
    from pxr import Usd, UsdShade

    assert usd_schema.register()  # False: something built the schema registry before this module's import
    stage = Usd.Stage.CreateInMemory()
    prim = UsdShade.Material.Define(stage, "/M").GetPrim()
    assert prim.ApplyAPI(usd_schema.SCHEMA_NAME) and prim.HasAPI(usd_schema.SCHEMA_NAME)
    assert prim.GetAttribute("neural:version").Get() == 1


REGISTERED_SCRIPT = """
    import json, sys
    from mtlx2neural import usd_schema
    assert usd_schema.register() and usd_schema.register()  # idempotent
    from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt, Gf

    expected = json.loads(sys.argv[1])
    reg = Usd.SchemaRegistry()
    assert reg.GetSchemaKind("NeuralMaterialAPI") == Usd.SchemaKind.SingleApplyAPI
    defn = reg.FindAppliedAPIPrimDefinition("NeuralMaterialAPI")
    assert sorted(defn.GetPropertyNames()) == sorted(expected), defn.GetPropertyNames()
    for name, (type_name, fallback) in expected.items():
        spec = defn.GetAttributeDefinition(name)
        assert str(spec.GetTypeName()) == type_name, (name, spec.GetTypeName())
        assert spec.GetFallbackValue() == fallback, (name, spec.GetFallbackValue())
        assert spec.GetDocumentation(), name
    assert defn.GetAttributeDefinition("neural:activation").GetMetadata("allowedTokens") == ["relu"]
    assert defn.GetAttributeDefinition("neural:alphaMode").GetMetadata("allowedTokens") == ["opaque", "mask", "blend"]

    stage = Usd.Stage.CreateInMemory()
    mat = UsdShade.Material.Define(stage, "/Looks/M")
    prim = mat.GetPrim()
    assert prim.CanApplyAPI("NeuralMaterialAPI")
    assert prim.ApplyAPI("NeuralMaterialAPI") and prim.HasAPI("NeuralMaterialAPI")
    assert prim.GetAttribute("neural:version").Get() == 1
    assert prim.GetAttribute("neural:proxyType").Get() == "tilted_cosine_aniso_ggx"
    prim.GetAttribute("neural:latentChannels").Set(8)
    prim.GetAttribute("neural:decoderLayers").Set(Vt.IntArray([64, 64, 64]))
    prim.GetAttribute("neural:latentTextures").Set(
        Sdf.AssetPathArray([Sdf.AssetPath("./M/latent0.exr"), Sdf.AssetPath("./M/latent1.exr")]))
    prim.GetAttribute("neural:latentResolution").Set(Gf.Vec2i(512, 256))
    prim.GetAttribute("neural:metrics:flip").Set(0.0625)
    assert prim.GetAttribute("neural:decoderLayers").Get() == Vt.IntArray([64, 64, 64])
    assert prim.GetAttribute("neural:latentResolution").Get() == Gf.Vec2i(512, 256)

    for path, define in (("/X", UsdGeom.Xform.Define), ("/Looks/S", UsdShade.Shader.Define)):
        ok, why = define(stage, path).GetPrim().CanApplyAPI("NeuralMaterialAPI")
        assert not ok and "Material" in why, (path, why)

    mesh = UsdGeom.Mesh.Define(stage, "/World/Mesh").GetPrim()
    UsdShade.MaterialBindingAPI.Apply(mesh).Bind(mat)
    stage.GetRootLayer().Export(sys.argv[2])
    print("ok")
"""


@pytest.fixture(scope="module")
def saved_asset(tmp_path_factory):
    """A layer written by a process with the plugin registered: a NeuralMaterialAPI Material bound to a mesh."""
    import json

    path = tmp_path_factory.mktemp("schema") / "asset.usda"
    assert _run(REGISTERED_SCRIPT, json.dumps(EXPECTED_ATTRS), str(path)).strip() == "ok"
    return path


def test_schema_registered_in_fresh_process(saved_asset):
    text = saved_asset.read_text()
    assert 'apiSchemas = ["NeuralMaterialAPI"]' in text
    assert "int[] neural:decoderLayers = [64, 64, 64]" in text


def test_asset_opens_without_plugin(saved_asset):
    """The API schema rides on a standard Material: no plugin, still a bound Material."""
    _run(f"""
        from pxr import Usd, UsdShade
        stage = Usd.Stage.Open({str(saved_asset)!r})
        assert Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("NeuralMaterialAPI") is None
        prim = stage.GetPrimAtPath("/Looks/M")
        assert prim.IsA(UsdShade.Material) and UsdShade.Material(prim)
        assert not prim.HasAPI("NeuralMaterialAPI")
        assert "NeuralMaterialAPI" in prim.GetPrimTypeInfo().GetAppliedAPISchemas()
        assert prim.GetAttribute("neural:latentChannels").Get() == 8
        assert list(prim.GetAttribute("neural:decoderLayers").Get()) == [64, 64, 64]
        mesh = stage.GetPrimAtPath("/World/Mesh")
        bound, rel = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
        assert bound and bound.GetPath() == "/Looks/M", bound
    """)


def test_register_after_schema_registry_is_built_reports_it():
    out = _run("""
        from pxr import Usd, UsdShade
        UsdShade.Material.Define(Usd.Stage.CreateInMemory(), "/M")  # builds the schema registry
        from mtlx2neural import usd_schema
        print(usd_schema.register(shaders=False))
    """)
    assert out.strip() == "False"


SDR_SCRIPT = """
    from pxr import Sdf, Sdr
    {setup}
    reg = Sdr.Registry()
    assert len(reg.GetShaderNodesByIdentifier("NeuralBSDF")) == 1
    node = reg.GetShaderNodeByIdentifier("NeuralBSDF")
    assert node is not None and reg.GetShaderNodeByName("NeuralBSDF") is not None
    assert node.GetSourceType() == ""  # universal info:sourceAsset
    assert node.GetResolvedImplementationURI().endswith("neural_bsdf.slang")
    assert node.GetResolvedDefinitionURI().endswith("NeuralBSDF.usda")
    assert sorted(node.GetShaderInputNames()) == sorted(
        ["latentTexture0", "latentTexture1", "latentTexture2", "latentTexture3",
         "weights", "weightsManifest", "st", "lod"]), node.GetShaderInputNames()
    assert sorted(node.GetAssetIdentifierInputNames()) == sorted(
        ["latentTexture0", "latentTexture1", "latentTexture2", "latentTexture3", "weights", "weightsManifest"])
    st = node.GetShaderInput("st")
    assert st.GetTypeAsSdfType().GetSdfType() == Sdf.ValueTypeNames.Float2 and st.IsConnectable()
    assert node.GetShaderInput("lod").GetDefaultValue() == -1.0
    assert node.GetShaderOutputNames() == ["surface"]
    assert node.GetShaderOutput("surface").GetMetadata()["renderType"] == "terminal surface"
    print("ok")
"""


def test_sdr_finds_neural_bsdf_through_env():
    """PXR_SDR_FS_PLUGIN_SEARCH_PATHS (+ ALLOWED_EXTS=usda), set before Sdr initialises; no register()."""
    assert _run(SDR_SCRIPT.format(setup=""), plugin_env=True).strip() == "ok"


@pytest.mark.parametrize("plugin_env", [False, True], ids=["no_env", "env_too"])
def test_register_adds_neural_bsdf_to_sdr(plugin_env):
    """register() adds the shader without environment variables, and no duplicate when they are set."""
    setup = "from mtlx2neural import usd_schema; assert usd_schema.register()"
    assert _run(SDR_SCRIPT.format(setup=setup), plugin_env=plugin_env).strip() == "ok"


def test_environment_prepends_once():
    env = usd_schema.environment({"PXR_PLUGINPATH_NAME": "/elsewhere", "PXR_SDR_FS_PLUGIN_ALLOWED_EXTS": "osl"})
    assert env["PXR_PLUGINPATH_NAME"] == os.pathsep.join([usd_plugin_path(), "/elsewhere"])
    assert env["PXR_SDR_FS_PLUGIN_ALLOWED_EXTS"] == "usda:osl"
    assert env["PXR_SDR_FS_PLUGIN_SEARCH_PATHS"] == str(usd_schema.shader_search_path())
    assert usd_schema.environment(env) == env
