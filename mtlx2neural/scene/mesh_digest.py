"""A digest of the mesh data a material's geometry maps are rasterised from (for the cache keys).

A graph that reads geometry (``position``, ``normal``, ``tangent``, ``bitangent``, ``geomcolor``,
``geompropvalue``) bakes the bound meshes into its latents (:mod:`mtlx2neural.scene.uv_raster`), so
editing one of those meshes must retrain the material. :func:`mesh_digest` hashes, per bound prim in
binding order, what :func:`mtlx2neural.scene.uv_raster.rasterise_meshes` reads:

- the prim path and, for a GeomSubset, its face indices (the mesh is its parent);
- ``points``, ``faceVertexCounts``, ``faceVertexIndices`` and ``orientation``;
- the UV set the layout is drawn from (its primvar name, interpolation and flattened values);
- the normals (``primvars:normals`` or ``normals``, with their interpolation);
- every primvar the material reads (``displayColor``/``displayOpacity`` for ``geomcolor``);
- the local-to-world transform at the default time (the world-space maps and the object/world
  spaces of the ``transform*`` nodes depend on it).

Arrays are hashed as float64/int64 bytes, so an authored value written with another precision but
equal numbers hashes equal. A prim that cannot be read hashes as its reason (the raster leaves it
out). Nothing else of the stage (other prims, lights, cameras) is hashed.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

import numpy as np

from mtlx2neural.scene.mesh_reading import attribute_value, texcoords

__all__ = ["mesh_digest"]


def mesh_digest(stage, prim_paths: Iterable[str], primvars: Iterable[str] = ()) -> str:
    """Hex sha256 of the mesh data of ``prim_paths`` on ``stage`` that the geometry maps read
    (module docstring), with the primvar names ``primvars`` the material reads."""
    # Local: pxr loads its plugins on import; only a material that reads geometry gets here.
    from pxr import Usd, UsdGeom


    h = hashlib.sha256()

    def put(tag: str, data: bytes) -> None:
        h.update(f"{tag}:{len(data)}:".encode() + data)

    def put_array(tag: str, value, dtype) -> None:
        if value is None:
            put(tag, b"none")
            return
        try:
            put(tag, np.ascontiguousarray(np.asarray(value, dtype=dtype)).tobytes())
        except (TypeError, ValueError):  # a non-numeric primvar (strings): its text
            put(tag, repr(list(value)).encode())

    names = list(dict.fromkeys(primvars))
    for path in prim_paths:
        put("prim", str(path).encode())
        prim = stage.GetPrimAtPath(str(path))
        if not prim or not prim.IsValid():
            put("missing", b"")
            continue
        if prim.IsA(UsdGeom.Subset):
            put_array("subset", attribute_value(UsdGeom.Subset(prim).GetIndicesAttr()), np.int64)
            prim = prim.GetParent()
        if not prim.IsA(UsdGeom.Mesh):
            put("type", prim.GetTypeName().encode())
            continue
        mesh = UsdGeom.Mesh(prim)
        put_array("points", attribute_value(mesh.GetPointsAttr()), np.float64)
        put_array("counts", attribute_value(mesh.GetFaceVertexCountsAttr()), np.int64)
        put_array("indices", attribute_value(mesh.GetFaceVertexIndicesAttr()), np.int64)
        put("orientation", str(mesh.GetOrientationAttr().Get()).encode())
        uv, how = texcoords(mesh)
        put("uv_interpolation", str(how).encode())
        put_array("uv", uv, np.float64)
        api = UsdGeom.PrimvarsAPI(mesh)
        for name in ("normals", *names):
            pv = api.GetPrimvar(name)
            if pv and pv.HasValue():
                values = pv.ComputeFlattened(Usd.TimeCode.Default())
                put(f"primvar:{name}", str(pv.GetInterpolation()).encode())
                put_array(f"values:{name}", None if values is None else list(values), np.float64)
            else:
                put(f"primvar:{name}", b"absent")
        put("normals_interpolation", str(mesh.GetNormalsInterpolation()).encode())
        put_array("normals", attribute_value(mesh.GetNormalsAttr()), np.float64)
        xf = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        put_array("transform", np.array(xf), np.float64)
    return h.hexdigest()
