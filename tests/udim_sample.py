"""A two-tile UDIM sample material for the UDIM latent tests (model, train, export, codegen).

Tiles on disk: 1001 (red), 1002 (blue) and 1011 (green), 8x8 constant-colour EXRs named
``base.<UDIM>.exr``; a diffuse ``standard_surface`` reads them as its base colour. The USD
stage holds one plane ``/World/Plane`` whose UVs span u in [0, 2], v in [0, 1]: it touches
tiles 1001 and 1002 only, so tile 1011 is on disk but never trained.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

COLOURS = {1001: (0.8, 0.05, 0.05), 1002: (0.05, 0.1, 0.8), 1011: (0.05, 0.8, 0.05)}
PLANE = "/World/Plane"


def write_tiles(folder: Path) -> str:
    """Write the three 8x8 tiles into ``folder``; returns the ``<UDIM>`` pattern."""
    from conftest import write_float_image

    folder.mkdir(parents=True, exist_ok=True)
    for udim, rgb in COLOURS.items():
        write_float_image(folder / f"base.{udim}.exr",
                          np.broadcast_to(np.array(rgb, dtype=np.float32), (8, 8, 3)).copy())
    return str(folder / "base.<UDIM>.exr")


def udim_reference(folder: Path):
    """The ReferenceMaterial of the diffuse UDIM material (tiles written into ``folder``)."""
    import MaterialX as mx

    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial

    pattern = write_tiles(folder)
    doc = mx.createDocument()
    img = doc.addNode("image", "base", "color3")
    img.setInputValue("file", pattern, "filename")
    s = doc.addNode("standard_surface", "s", "surfaceshader")
    s.setInputValue("base", 1.0, "float")
    s.setInputValue("specular", 0.0, "float")
    s.setConnectedNode("base_color", img)
    doc.addMaterialNode("UdimDiffuse", s)
    return ReferenceMaterial(compile_material(doc, "UdimDiffuse"))


def write_plane_stage(path: Path) -> Path:
    """A USD stage with the plane ``PLANE`` (two triangles' quad, faceVarying ``st`` over
    [0, 2] x [0, 1]); returns ``path``."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, PLANE)
    mesh.CreatePointsAttr([(0, 0, 0), (2, 0, 0), (2, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray([(0, 0), (2, 0), (2, 1), (0, 1)]))
    stage.GetRootLayer().Save()
    return path
