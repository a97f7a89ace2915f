"""Partial failure: a material that cannot be converted is skipped and the others convert (exit 3);
nothing convertible or ``--strict`` is exit 2 with nothing written; unparsable values are clear
input errors; a texture named with another case is read with a warning (``--strict``: an error).

The one conversion here trains nothing (``--iterations 0 --allow-untrained``): these tests check
exit codes, messages and records, not fidelity.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from cli_helpers import assert_clean_input_error, run_cli
from conftest import write_float_image
from materials import document, image, standard_surface, usd_painted_ball

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.pipeline.plan import plan_materials
from mtlx2neural.scene import load_asset
from mtlx2neural.scene.dependencies import input_files
from mtlx2neural.train.config import preset

TINY = preset("fast", iterations=20, batch=256)
HAIR_SHADERS = '''
        def Material "Hair"
        {
            token outputs:mtlx:surface.connect = </World/Looks/Hair/Surf.outputs:surface>
            def Shader "Surf"
            {
                uniform token info:id = "ND_surface"
                token inputs:bsdf.connect = </World/Looks/Hair/H.outputs:out>
                token outputs:surface
            }
            def Shader "H"
            {
                uniform token info:id = "ND_chiang_hair_bsdf"
                token outputs:out
            }
        }
'''
BAD_VALUE = '''
        def Material "Bad"
        {
            token outputs:mtlx:surface.connect = </World/Looks/Bad/SR.outputs:surface>
            def Shader "SR"
            {
                uniform token info:id = "ND_standard_surface_surfaceshader"
                string inputs:base = "abc"
                token outputs:surface
            }
        }
'''


def two_material_stage(second: str = HAIR_SHADERS, name: str = "Hair", paint: bool = True) -> str:
    """A USD layer: /World/Ball bound to /World/Looks/Paint (a plain standard_surface, when
    ``paint``) and /World/Other bound to /World/Looks/<name>, defined by ``second``."""
    text = usd_painted_ball("color3f inputs:base_color = (0.2, 0.5, 0.8)",
                            metadata='(\n    defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n')
    other = ('    def Sphere "Other" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
             f"        rel material:binding = </World/Looks/{name}>\n    }}\n")
    text = text.replace('    def Scope "Looks"\n', other + '    def Scope "Looks"\n', 1)
    text = text.replace("            }\n        }\n    }\n}\n", "            }\n        }\n" + second + "    }\n}\n", 1)
    if not paint:  # unbind the ball: only the second material is selected
        text = text.replace("        rel material:binding = </World/Looks/Paint>\n", "", 1)
    return text


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_plan_skips_an_unsupported_material_and_names_its_node(tmp_path):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage())
    sources = load_asset(asset).materials
    assert [s.name for s in sources] == ["/World/Looks/Paint", "/World/Looks/Hair"]
    failures = []
    plans = plan_materials(sources, TINY, failures=failures)
    assert [p.name for p in plans] == ["/World/Looks/Paint"]
    assert [(f.material, f.node) for f in failures] == [("/World/Looks/Hair", "H")]
    assert "chiang_hair_bsdf" in failures[0].reason and str(asset) in failures[0].reason
    with pytest.raises(UnsupportedNodeError, match="chiang_hair_bsdf"):  # no list: all or nothing
        plan_materials(sources, TINY)


def test_load_keeps_going_past_a_material_whose_value_does_not_fit(tmp_path):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(BAD_VALUE, "Bad"))
    scene = load_asset(asset, keep_going=True)
    assert [s.name for s in scene.materials] == ["/World/Looks/Paint"]
    assert [n for n, _ in scene.failed] == ["/World/Looks/Bad"]
    assert "'abc'" in str(scene.failed[0][1]) and "/World/Looks/Bad/SR" in str(scene.failed[0][1])
    with pytest.raises(InputError, match="abc"):
        load_asset(asset)


def _mis_cased(tmp_path) -> str:
    """A .mtlx naming baseColor.png beside a basecolor.png (seeded pixels); its path."""
    probe = tmp_path / "probe"
    probe.write_bytes(b"")
    if (tmp_path / "PROBE").exists():
        pytest.skip("the temporary folder's file system is case-insensitive")
    rng = np.random.default_rng(3)
    write_float_image(tmp_path / "basecolor.png", rng.random((4, 4, 3)).astype(np.float32))
    mtlx = tmp_path / "tex.mtlx"
    mtlx.write_text(document(image("albedo", "baseColor.png"),
                             standard_surface("Tex", "SR", base_color={"node": "albedo"})))
    return mtlx


def test_a_texture_named_with_another_case_is_read_with_a_warning_and_strict_refuses_it(tmp_path):
    mtlx = _mis_cased(tmp_path)
    sources = load_asset(mtlx).materials
    with pytest.warns(UserWarning, match="differs only in case"):
        (plan,) = plan_materials(sources, TINY)
    assert plan.grid_kind == "native" and plan.grid == (4, 4)  # the real file was read
    (warning,) = plan.warnings
    assert str(tmp_path / "baseColor.png") in warning and str(tmp_path / "basecolor.png") in warning
    failures = []
    assert plan_materials(sources, TINY, failures=failures, strict=True) == []
    assert failures[0].node == "albedo" and "--strict" in failures[0].reason


def test_the_mis_cased_texture_is_an_input_file_under_its_real_name(tmp_path):
    mtlx = _mis_cased(tmp_path)
    files = input_files(mtlx, load_asset(mtlx).materials)  # what no output may overwrite
    assert (tmp_path / "basecolor.png").resolve() in files


def test_cli_inspect_reads_the_mis_cased_texture_and_warns(tmp_path, capsys):
    mtlx = _mis_cased(tmp_path)
    with pytest.warns(UserWarning, match="differs only in case"):
        code, out, err = run_cli(capsys, "inspect", mtlx)
    assert code == 0, err
    assert "warning: texture file" in out and "basecolor.png" in out


def test_cli_strict_exits_2_and_writes_nothing(tmp_path, capsys):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage())
    before = _digest(asset)
    code, out, err = run_cli(capsys, asset, "--strict", "--iterations", "0", "--allow-untrained",
                             "--device", "cpu", "--workers", "1", "--quiet")
    assert_clean_input_error(code, out, err, "H", "chiang_hair_bsdf", str(asset))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]
    assert _digest(asset) == before


@pytest.mark.parametrize("second,name", [(HAIR_SHADERS, "Hair"), (BAD_VALUE, "Bad")])
def test_cli_nothing_convertible_exits_2_and_writes_nothing(tmp_path, capsys, second, name):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(second, name, paint=False))
    before = _digest(asset)
    code, out, err = run_cli(capsys, asset, "--iterations", "0", "--allow-untrained", "--device", "cpu",
                             "--workers", "1", "--quiet")
    assert_clean_input_error(code, out, err, "no material could be converted", f"/World/Looks/{name}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]
    assert _digest(asset) == before


BAD_FLOAT = document(standard_surface("M", "SR", base="abc"))
BAD_MODE = document(image("albedo", "albedo.png").replace(
    "  </image>", '    <input name="uaddressmode" type="string" value="bogus" />\n  </image>'),
    standard_surface("M", "SR", base_color={"node": "albedo"}))


@pytest.mark.parametrize("text,expected", [
    (BAD_FLOAT, ("Node 'SR'", "'base'", "'abc'", "does not parse as a float")),
    (BAD_MODE, ("node 'albedo'", "uaddressmode='bogus'", "periodic")),
])
def test_cli_unparsable_values_are_input_errors_naming_file_and_node(tmp_path, capsys, text, expected):
    write_float_image(tmp_path / "albedo.png", np.full((2, 2, 3), 0.5, np.float32))
    mtlx = tmp_path / "bad.mtlx"
    mtlx.write_text(text)
    for argv in (("inspect", mtlx), (mtlx, "--iterations", "0", "--allow-untrained", "--device", "cpu", "--quiet")):
        code, out, err = run_cli(capsys, *argv)
        assert_clean_input_error(code, out, err, str(mtlx), *expected)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["albedo.png", "bad.mtlx"]


@pytest.mark.slow  # two untrained conversions (export, baseline fit, renders): tens of seconds on 2 cores
def test_cli_skips_the_unsupported_material_exits_3_and_records_it(tmp_path, capsys):
    from pxr import Sdf

    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage())
    before = _digest(asset)
    args = ("--iterations", "0", "--allow-untrained", "--device", "cpu", "--workers", "1", "--quiet")
    code, out, err = run_cli(capsys, asset, *args)
    assert code == 3, err
    assert "Traceback" not in err
    assert "mtlx2neural: skipped /World/Looks/Hair (node 'H'):" in err and "chiang_hair_bsdf" in err
    assert "/World/Looks/Paint:" in out
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "scene_neural.usda"))
    record = dict(layer.customLayerData)["mtlx2neural"]
    assert list(record["materials"]) == ["/World/Looks/Paint"]
    assert list(record["skippedMaterials"]) == ["/World/Looks/Hair"]
    assert "chiang_hair_bsdf" in record["skippedMaterials"]["/World/Looks/Hair"]
    assert layer.GetPrimAtPath("/World/Looks/Hair") is None  # keeps its original network only
    assert _digest(asset) == before
    # the supported material alone: exit 0, and the layer no longer lists anything skipped
    asset.write_text(usd_painted_ball("color3f inputs:base_color = (0.2, 0.5, 0.8)"))
    code, out, err = run_cli(capsys, asset, *args)
    assert code == 0, err
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "scene_neural.usda"))
    layer.Reload()
    assert "skippedMaterials" not in dict(layer.customLayerData)["mtlx2neural"]


def test_the_library_result_carries_the_failures(monkeypatch, tmp_path):
    from mtlx2neural import api
    from mtlx2neural.pipeline.convert import Summaries

    summaries = Summaries([{"material": "/World/Looks/Paint"}])
    summaries.skipped, summaries.kept, summaries.folder = [], [], tmp_path
    summaries.layer = tmp_path / "scene_neural.usda"
    summaries.failed = [{"material": "/World/Looks/Hair", "node": "H", "reason": "unsupported"}]
    monkeypatch.setattr(api, "convert_asset", lambda *_: summaries)
    monkeypatch.setattr(api, "_open_layer", lambda path: None)
    result = api.convert(tmp_path / "scene.usda")
    assert result.failed == summaries.failed and result.skipped == []


@pytest.mark.slow
def test_a_material_kept_by_a_material_run_warns_when_its_input_changed(tmp_path, capsys):
    from materials import TWO_MTLX

    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    tiny = ("--iterations", "0", "--allow-untrained", "--quiet", "--workers", "1")
    code, _, err = run_cli(capsys, asset, *tiny)
    assert code == 0, err
    # Blue changes in the input; only Red is converted again, Blue is kept from the first run.
    asset.write_text(TWO_MTLX.replace("0.1, 0.1, 0.8", "0.9, 0.9, 0.1"))
    with pytest.warns(UserWarning, match=r"keeping Blue as it was converted, but its input has changed.*--force"):
        code, _, err = run_cli(capsys, asset, "--material", "Red", *tiny)
    assert code == 0, err
    # Unchanged, no warning.
    asset.write_text(TWO_MTLX)
    import warnings as w

    with w.catch_warnings():
        w.simplefilter("error", UserWarning)
        code, _, err = run_cli(capsys, asset, "--material", "Red", *tiny)
    assert code == 0, err


def test_a_mtlx_file_with_one_invalid_material_converts_the_other(tmp_path, capsys):
    bogus = ('  <bogus_node name="bg" type="color3" />\n'
             + standard_surface("Blue", "SR_b", base_color={"node": "bg"}))
    asset = tmp_path / "two.mtlx"
    asset.write_text(document(standard_surface("Red", "SR_red", base_color=(0.8, 0.1, 0.1)), bogus))
    before = _digest(asset)
    code, out, err = run_cli(capsys, asset, "--iterations", "0", "--allow-untrained", "--quiet", "--workers", "1")
    assert code == 3, err  # as a USD stage with one bad material: the other converts
    assert "skipped Blue" in err and "bogus_node" in err and "Red" in out
    assert (tmp_path / "two_neural" / "Red" / "neural" / "weights.bin").is_file()
    assert not (tmp_path / "two_neural" / "Blue").exists()
    # --strict: the whole file is refused, nothing written
    code, out, err = run_cli(capsys, asset, "--strict", "-o", tmp_path / "strict", "--iterations", "0",
                             "--allow-untrained", "--quiet")
    assert code == 2 and not (tmp_path / "strict").exists()
    assert _digest(asset) == before
