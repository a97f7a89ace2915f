"""Reading the meshes a material is bound to: topology, UVs, primvars, triangles, transforms.

The one home of mesh reading for every scene module that needs geometry: the texel-density
measure (:mod:`.texel_density`), the UV-space geometry maps (:mod:`.uv_raster`), the mesh digest
of the cache key (:mod:`.mesh_digest`), the UDIM tiles a mesh touches (:mod:`.udim_tiles`) and the
in-scene render (:mod:`.stage_render`).

Conventions:

- a bound prim is a ``UsdGeom.Mesh`` or a ``UsdGeom.Subset`` of one (its parent mesh, only the
  subset's faces);
- values are read at the default time, else at the earliest time sample (animated meshes);
- the UV set is ``st`` when it has a value, else the first ``texCoord2[fdh][]`` primvar with one
  (:func:`uv_primvar`), ``vertex``/``varying`` or ``faceVarying``, flattened (indexed primvars
  resolved) by ``ComputeFlattened``;
- polygons are triangulated as fans (0, k, k+1) (:func:`fan_triangles`); triangle corners are
  *face-vertex positions* (indices into ``faceVertexIndices``);
- matrices are 4x4 in USD's row-vector convention (world = [p, 1] M); positions in stage units.

Every reader returns a reason (a ``str``) instead of raising when a prim cannot be read, so that
callers can name the prim and go on with the others.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

__all__ = ["MeshTopology", "attribute_value", "corner_values", "fan_triangles", "mesh_triangles",
           "object_to_world", "primvar_values", "read_topology", "texcoords", "uv_primvar"]


def attribute_value(attr):
    """The attribute's value at the default time, else at its earliest time sample (animated meshes)."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Usd

    value = attr.Get(Usd.TimeCode.Default())
    return attr.Get(Usd.TimeCode.EarliestTime()) if value is None else value


def uv_primvar(mesh):
    """The primvar a mesh's UV layout is read from: ``st`` when it has a value, else the first
    ``texCoord2[fdh][]`` primvar with one; None when there is none."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Sdf, UsdGeom

    api = UsdGeom.PrimvarsAPI(mesh)
    pv = api.GetPrimvar("st")
    if not (pv and pv.HasValue()):
        uv_types = (Sdf.ValueTypeNames.TexCoord2fArray, Sdf.ValueTypeNames.TexCoord2dArray,
                    Sdf.ValueTypeNames.TexCoord2hArray)
        pv = next((p for p in api.GetPrimvarsWithValues() if p.GetTypeName() in uv_types), None)
    return pv


def texcoords(mesh):
    """(flattened [N, 2] float64 texture coordinates, interpolation) of :func:`uv_primvar`, or (None,
    why not)."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Usd, UsdGeom

    pv = uv_primvar(mesh)
    if pv is None:
        return None, "no st primvar (nor any texCoord2f[] primvar)"
    name = pv.GetPrimvarName()
    how = pv.GetInterpolation()
    if how not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying, UsdGeom.Tokens.faceVarying):
        return None, f"primvar {name} has {how} interpolation: its texture coordinates span no area"
    values = pv.ComputeFlattened(Usd.TimeCode.Default())
    if values is None:
        values = pv.ComputeFlattened(Usd.TimeCode.EarliestTime())
    if values is None or len(values) == 0:
        return None, f"primvar {name} has no values"
    uv = np.asarray(values, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        return None, f"primvar {name} is not 2D ({pv.GetTypeName()})"
    return uv, str(how)


def fan_triangles(counts: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """[T, 3] face-vertex positions of the fan triangles (0, k, k+1) of every kept polygon
    (``counts``: vertices per polygon; ``keep``: [F] bool)."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_tris = np.where(keep, np.maximum(counts - 2, 0), 0)
    total = int(n_tris.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64)
    first = np.repeat(starts, n_tris)
    offsets = np.repeat(np.cumsum(n_tris) - n_tris, n_tris)
    k = np.arange(total, dtype=np.int64) - offsets + 1  # 1 .. count-2 within each polygon
    return np.stack([first, first + k, first + k + 1], axis=1)


def primvar_values(api, name: str, n_points: int, n_faces: int, n_fv: int):
    """(values [K, C] float64, interpolation) of primvar ``name`` of a ``UsdGeom.PrimvarsAPI``, or
    None when it is absent or its count does not fit its interpolation (``n_points`` points,
    ``n_faces`` faces, ``n_fv`` face-vertices)."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Usd

    pv = api.GetPrimvar(name)
    if not (pv and pv.HasValue()):
        return None
    values = pv.ComputeFlattened(Usd.TimeCode.Default())
    if values is None:
        values = pv.ComputeFlattened(Usd.TimeCode.EarliestTime())
    if values is None or len(values) == 0:
        return None
    arr = np.asarray(values, dtype=np.float64)
    arr = arr.reshape(len(arr), -1)
    how = str(pv.GetInterpolation())
    expected = {"constant": 1, "uniform": n_faces, "vertex": n_points, "varying": n_points, "faceVarying": n_fv}
    if how == "constant":
        arr = arr[:1]
    if len(arr) != expected.get(how, -1):
        return None
    return arr, how


def corner_values(arr, how, tris, indices, face_of_tri):
    """[T, 3, C] per-corner values of a primvar (:func:`primvar_values`) for the fan triangles ``tris``
    (face-vertex positions; ``indices``: faceVertexIndices; ``face_of_tri``: [T] polygon of each)."""
    if how == "constant":
        return np.broadcast_to(arr[0], (len(tris), 3, arr.shape[1]))
    if how == "uniform":
        return np.repeat(arr[face_of_tri][:, None, :], 3, axis=1)
    if how == "faceVarying":
        return arr[tris]
    return arr[indices[tris]]


@dataclass
class MeshTopology:
    """A mesh as read: the ``UsdGeom.Mesh`` (``mesh``), its ``points`` [P, 3] (stage units, object
    space), ``counts`` [F] vertices per polygon, ``indices`` [sum(counts)] faceVertexIndices, the
    faces to use (``keep`` [F] bool: a GeomSubset's faces, else all), ``holes`` [F] bool (the mesh's
    ``holeIndices``) and the UV set (``uv`` [N, 2] and ``uv_how``, its interpolation; ``uv`` None:
    ``uv_how`` says why)."""

    mesh: object
    points: np.ndarray
    counts: np.ndarray
    indices: np.ndarray
    keep: np.ndarray
    holes: np.ndarray
    uv: np.ndarray | None
    uv_how: str
    subset: bool

    def uv_corners(self, tris: np.ndarray) -> np.ndarray:
        """[T, 3, 2] texture coordinates at the corners of ``tris`` (face-vertex positions)."""
        return self.uv[tris] if self.uv_how == "faceVarying" else self.uv[self.indices[tris]]

    def uv_count_error(self) -> str | None:
        """Why the UV values do not fit the mesh, or None when they do (or there are none)."""
        if self.uv is None:
            return None
        if self.uv_how == "faceVarying":
            if len(self.uv) != len(self.indices):
                return f"texture coordinates: {len(self.uv)} faceVarying values for {len(self.indices)} face-vertices"
        elif len(self.uv) != len(self.points):
            return f"texture coordinates: {len(self.uv)} {self.uv_how} values for {len(self.points)} points"
        return None


def read_topology(stage, path) -> MeshTopology | str:
    """The mesh (or GeomSubset of a mesh) at ``path`` on ``stage``, or the reason it cannot be read: no
    such prim, a subset of non-face elements, not a mesh, no points or faces, malformed topology."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(str(path))
    if not prim or not prim.IsValid():
        return "no such prim"
    faces = None
    if prim.IsA(UsdGeom.Subset):
        subset = UsdGeom.Subset(prim)
        if subset.GetElementTypeAttr().Get() not in (None, UsdGeom.Tokens.face):
            return "GeomSubset of non-face elements"
        faces = np.asarray(subset.GetIndicesAttr().Get(Usd.TimeCode.Default()) or [], dtype=np.int64)
        prim = prim.GetParent()
    if not prim.IsA(UsdGeom.Mesh):
        return f"not a mesh ({prim.GetTypeName() or 'untyped'})"
    mesh = UsdGeom.Mesh(prim)
    points, counts, indices = (attribute_value(a) for a in (mesh.GetPointsAttr(), mesh.GetFaceVertexCountsAttr(),
                                                            mesh.GetFaceVertexIndicesAttr()))
    if points is None or counts is None or indices is None or len(points) == 0:
        return "mesh has no points or faces"
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if counts.sum() != len(indices) or (len(indices) and (indices.min() < 0 or indices.max() >= len(points))):
        return "malformed topology (faceVertexCounts/faceVertexIndices do not match the points)"
    keep = np.ones(len(counts), dtype=bool)
    if faces is not None:
        keep[:] = False
        keep[faces[(faces >= 0) & (faces < len(counts))]] = True
    holes = np.zeros(len(counts), dtype=bool)
    hole_indices = attribute_value(mesh.GetHoleIndicesAttr())
    if hole_indices is not None and len(hole_indices):
        hole_indices = np.asarray(hole_indices, dtype=np.int64)
        holes[hole_indices[(hole_indices >= 0) & (hole_indices < len(counts))]] = True
    uv, how = texcoords(mesh)
    return MeshTopology(mesh, points, counts, indices, keep, holes, uv, how, faces is not None)


def object_to_world(stage, path: str) -> np.ndarray:
    """The 4x4 local-to-world matrix (row-vector convention) of the prim at ``path`` (a GeomSubset's
    parent) at the default time."""
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(str(path))
    if prim.IsA(UsdGeom.Subset):
        prim = prim.GetParent()
    return np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)


def _normalise(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def mesh_triangles(stage, path: str, primvars: Iterable[str], need_uv: bool = True):
    """(uv [T,3,2], corners {key: [T,3,C]}) of the mesh or GeomSubset at ``path``, or a reason why not.

    ``corners`` holds, per triangle corner, ``position:object``/``position:world`` (stage units),
    ``normal:*`` (the authored normals, else the geometric normal, flipped for a left-handed mesh),
    ``tangent:*`` (dP/du made orthogonal to the normal), ``bitangent:*`` (normal x tangent, signed
    along dP/dv) in object and world space, and ``primvar:NAME`` for each of ``primvars`` the mesh
    has (:mod:`.uv_raster` documents the maps made of them). Hole faces are kept (the UV layout is
    drawn whole). ``need_uv=False`` (rendering the mesh, :mod:`.stage_render`): a mesh without UVs
    reads uv 0."""
    topo = read_topology(stage, path)
    if isinstance(topo, str):
        return topo
    points, counts, indices, mesh = topo.points, topo.counts, topo.indices, topo.mesh
    if topo.uv is None and not need_uv:
        topo.uv, topo.uv_how = np.zeros((len(points), 2)), "vertex"
    if topo.uv is None:
        return f"no UVs ({topo.uv_how})"
    if (why := topo.uv_count_error()) is not None:
        return why
    tris = fan_triangles(counts, topo.keep)
    if len(tris) == 0:
        return "no polygons"
    # Local: pxr loads its plugins on import; only reading a real stage needs it.
    from pxr import UsdGeom

    face_of_fv = np.repeat(np.arange(len(counts)), counts)
    face_of_tri = face_of_fv[tris[:, 0]]
    xf = object_to_world(stage, path)
    world_pts = np.hstack([points, np.ones((len(points), 1))]) @ xf
    world_pts = world_pts[:, :3] / world_pts[:, 3:4]
    tuv = topo.uv_corners(tris)
    p_obj = points[indices[tris]]  # [T, 3, 3]
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    e1, e2 = p_obj[:, 1] - p_obj[:, 0], p_obj[:, 2] - p_obj[:, 0]
    face_n = _normalise(np.cross(e1, e2)) * (-1.0 if left else 1.0)
    api = UsdGeom.PrimvarsAPI(mesh)
    n_fv = len(indices)
    normals = primvar_values(api, "normals", len(points), len(counts), n_fv)  # primvars:normals wins over normals
    raw = attribute_value(mesh.GetNormalsAttr()) if normals is None else None
    if raw is not None:
        how_n = str(mesh.GetNormalsInterpolation())
        if len(raw) == {"faceVarying": n_fv, "uniform": len(counts)}.get(how_n, len(points)):
            normals = (np.asarray(raw, dtype=np.float64).reshape(-1, 3), how_n)
    n_obj = (_normalise(corner_values(*normals, tris, indices, face_of_tri)) if normals is not None
             else np.repeat(face_n[:, None], 3, axis=1))
    # dP/du, dP/dv of each triangle from its UV derivatives.
    d1, d2 = tuv[:, 1] - tuv[:, 0], tuv[:, 2] - tuv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    det = np.where(det == 0, 1e-30, det)[:, None]
    dpdu = (d2[:, 1:2] * e1 - d1[:, 1:2] * e2) / det
    dpdv = (d1[:, 0:1] * e2 - d2[:, 0:1] * e1) / det
    t_obj = dpdu[:, None, :] - (n_obj * dpdu[:, None, :]).sum(-1, keepdims=True) * n_obj
    t_obj = _normalise(t_obj)
    b_obj = np.cross(n_obj, t_obj)
    hand = np.sign((b_obj * dpdv[:, None, :]).sum(-1, keepdims=True))
    b_obj = b_obj * np.where(hand == 0, 1.0, hand)
    lin = xf[:3, :3]  # row-vector convention: world = p @ lin (+ translation)
    inv_t = np.linalg.inv(lin).T
    corners = {"position:object": p_obj, "position:world": world_pts[indices[tris]],
               "normal:object": n_obj, "normal:world": _normalise(n_obj @ inv_t),
               "tangent:object": t_obj, "tangent:world": _normalise(t_obj @ lin),
               "bitangent:object": b_obj, "bitangent:world": _normalise(b_obj @ lin)}
    for name in primvars:
        found = primvar_values(api, name, len(points), len(counts), n_fv)
        if found is not None:
            corners[f"primvar:{name}"] = corner_values(*found, tris, indices, face_of_tri).astype(np.float64)
    return tuv, corners
