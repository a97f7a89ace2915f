"""plan_materials' cache keys: the training version and the bound meshes of a geometry-reading graph."""

from __future__ import annotations

import pytest
from materials import usd_quad_reading_position

from mtlx2neural.pipeline import source_hash as sh
from mtlx2neural.pipeline.plan import plan_materials
from mtlx2neural.train.config import preset

pytest.importorskip("pxr", reason="usd-core is needed for a USD stage")

CFG = preset("fast", iterations=2, batch=64)
POINTS = "point3f[] points = [(0, 0, 0), (2, 0, 0), (2, 3, 0), (0, 3, 0)]"
OTHER = ('    def Mesh "Other" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
         '        point3f[] points = [(0, 0, 5), (1, 0, 5), (1, 1, 5), (0, 1, 5)]\n'
         '        int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n'
         '        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")\n'
         '        rel material:binding = </World/Looks/U>\n    }\n')
UNIFORM = ('        def Material "U"\n        {\n'
           '            token outputs:mtlx:surface.connect = </World/Looks/U/S.outputs:surface>\n'
           '            def Shader "S"\n            {\n'
           '                uniform token info:id = "ND_standard_surface_surfaceshader"\n'
           '                color3f inputs:base_color = (0.2, 0.5, 0.7)\n'
           '                token outputs:surface\n            }\n        }\n')


def two_materials(quad_points: str = POINTS, other_z: str = "5", translate: str = "(10, 0, 0)") -> str:
    """/World/Looks/M reads object position on /World/Quad; /World/Looks/U (uniform, reads no geometry)
    is bound to /World/Other."""
    text = usd_quad_reading_position("world")
    text = text.replace(POINTS, quad_points).replace("(10, 0, 0)", translate)
    text = text.replace('def Xform "World"\n{\n', 'def Xform "World"\n{\n' + OTHER.replace(", 5)", f", {other_z})"))
    return text.replace('    def Scope "Looks"\n    {\n', '    def Scope "Looks"\n    {\n' + UNIFORM)


def keys(tmp_path, name: str, text: str) -> dict[str, tuple[str, str]]:
    """{material: (cache key, content hash)} of the stage ``text`` written to ``tmp_path/name``."""
    # Local: the scene loader opens the stage through pxr, which the module skips without.
    from mtlx2neural.scene import load_asset

    path = tmp_path / name
    path.write_text(text)
    plans = plan_materials(load_asset(str(path)).materials, CFG, asset=str(path))
    return {p.name: (p.digest, p.content) for p in plans}


def test_editing_a_bound_mesh_changes_only_the_geometry_reading_material(tmp_path):
    # Same file name each time: the stage path is part of a geometry-reading material's key.
    base = keys(tmp_path, "s.usda", two_materials())
    again = keys(tmp_path, "s.usda", two_materials())
    assert set(base) == {"/World/Looks/M", "/World/Looks/U"} and again == base  # deterministic
    moved = keys(tmp_path, "s.usda", two_materials(quad_points=POINTS.replace("(2, 3, 0)", "(2, 3.5, 0)")))
    assert moved["/World/Looks/M"][0] != base["/World/Looks/M"][0]  # a point of the read mesh
    assert moved["/World/Looks/M"][1] != base["/World/Looks/M"][1]  # and the content hash (no false sharing)
    assert moved["/World/Looks/U"] == base["/World/Looks/U"]
    shifted = keys(tmp_path, "s.usda", two_materials(translate="(11, 0, 0)"))
    assert shifted["/World/Looks/M"][0] != base["/World/Looks/M"][0]  # the transform (world position)
    other = keys(tmp_path, "s.usda", two_materials(other_z="6"))
    # The uniform material's own mesh changed, but it reads no geometry; M's meshes are untouched.
    assert other["/World/Looks/U"] == base["/World/Looks/U"] and other["/World/Looks/M"] == base["/World/Looks/M"]


def test_the_training_version_is_hashed(tmp_path, monkeypatch):
    base = keys(tmp_path, "s.usda", two_materials())
    monkeypatch.setattr(sh, "TRAINING_VERSION", sh.TRAINING_VERSION + 1)
    bumped = keys(tmp_path, "s.usda", two_materials())
    for name in base:
        assert bumped[name][0] != base[name][0] and bumped[name][1] != base[name][1]
    assert sh.TRAINING_VERSION >= 2  # monkeypatch restores it after the test; 2: the LEAN tangent change
