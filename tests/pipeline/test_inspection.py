"""``inspect``'s report (mtlx2neural.pipeline.inspection): the geometric inputs a material reads."""

from __future__ import annotations

import pytest
from materials import document, standard_surface, usd_quad_reading_position

from mtlx2neural.pipeline.inspection import format_report, inspect_asset
from mtlx2neural.scene.uv_raster import SPHERE


def test_usd_material_lists_its_geometric_inputs_and_the_mesh_prims(tmp_path):
    pytest.importorskip("pxr", reason="usd-core is needed for a USD stage")
    path = tmp_path / "quad.usda"
    path.write_text(usd_quad_reading_position("world"))
    report = inspect_asset(str(path))
    (m,) = report["materials"]
    assert m["geometry_inputs"] == [{"node": "P", "kind": "position", "space": "world",
                                     "source": "mesh prims /World/Quad"}]
    text = format_report(report)
    assert "geometric inputs:" in text and "position     world  (P)  from mesh prims /World/Quad" in text


def test_mtlx_material_reading_normal_names_the_sphere_default(tmp_path):
    path = tmp_path / "n.mtlx"
    path.write_text(document(
        '  <normal name="N" type="vector3">\n    <input name="space" type="string" value="world" />\n  </normal>\n'
        '  <convert name="C" type="color3">\n    <input name="in" type="vector3" nodename="N" />\n  </convert>\n',
        standard_surface("M", "SR", base_color={"node": "C"})))
    (m,) = inspect_asset(str(path))["materials"]
    assert [(g["kind"], g["space"], g["source"]) for g in m["geometry_inputs"]] == [("normal", "world", SPHERE)]
    assert any("unit sphere" in a for a in m["approximations"])


def test_material_reading_no_geometry_lists_none(tmp_path):
    path = tmp_path / "red.mtlx"
    path.write_text(document(standard_surface("Red", "SR", base_color=(0.8, 0.1, 0.1))))
    report = inspect_asset(str(path))
    assert report["materials"][0]["geometry_inputs"] == []
    assert "geometric inputs" not in format_report(report)
