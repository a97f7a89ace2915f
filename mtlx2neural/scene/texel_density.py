"""How much surface one unit of UV space covers: metres per UV unit of a material's meshes.

``--texel-density D`` (latent texels per metre of surface, the game-art convention:
512 = 5.12 texels/cm) turns this into the grid a material needs: ``D`` times the
metres one UV unit spans, in texels per UV unit (:func:`texels_per_uv`), which
:mod:`mtlx2neural.pipeline.plan` compares with the textures' grid.

For each bound ``UsdGeom.Mesh`` (a ``UsdGeom.Subset``: its parent mesh, only the
subset's faces; holes left out) :func:`mesh_density` takes the texture-coordinate
primvar (``st``, else the first ``texCoord2f[]`` primvar; ``vertex``/``varying`` and
``faceVarying`` interpolation, indexed or not, flattened by ``ComputeFlattened``),
triangulates every polygon as a fan, and sums the triangles' areas in world space
(points through ``ComputeLocalToWorldTransform`` at the default time, in square
metres through the stage's ``metersPerUnit``, which USD defaults to 0.01 when
unauthored) and in UV space. Metres per UV unit = sqrt(world area m^2 / UV area):
the side of the square of surface one UV unit covers on average. A material's value
is the largest over its meshes (:func:`surface_density`): the mesh that needs the
most texels decides.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from mtlx2neural.scene.usd_stage import is_stage, open_stage, stage_view

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")


@dataclass
class MeshDensity:
    """One mesh (or GeomSubset) of a material."""

    prim: str
    """USD path of the bound prim (the GeomSubset's own path for a subset)."""
    world_area_m2: float
    """Its surface area in world space, square metres."""
    uv_area: float
    """Its area in UV space (UV units squared; overlapping or mirrored UVs count each time)."""

    @property
    def metres_per_uv(self) -> float:
        """sqrt(world area / UV area): metres of surface per UV unit."""
        return math.sqrt(self.world_area_m2 / self.uv_area)


@dataclass
class SurfaceDensity:
    """Metres per UV unit over the prims bound to one material."""

    meshes: list[MeshDensity] = field(default_factory=list)
    """The meshes measured."""
    skipped: list[tuple[str, str]] = field(default_factory=list)
    """(prim path, reason) for each bound prim that could not be measured."""
    note: str | None = None
    """Why nothing could be measured (no geometry at all), else None."""
    meters_per_unit: float = 0.01
    """The stage's ``metersPerUnit``."""
    unit_authored: bool = False
    """Whether the stage authors ``metersPerUnit`` (else USD's default, 0.01: centimetres)."""

    @property
    def metres_per_uv(self) -> float | None:
        """Metres per UV unit of the most demanding mesh (the largest value); None when none was measured."""
        return max((m.metres_per_uv for m in self.meshes), default=None)

    def reason(self) -> str:
        """Why :attr:`metres_per_uv` is None, in a line (the skipped prims, or :attr:`note`)."""
        if self.note:
            return self.note
        shown = "; ".join(f"{p}: {r}" for p, r in self.skipped[:3])
        more = f"; and {len(self.skipped) - 3} more" if len(self.skipped) > 3 else ""
        return f"no bound mesh has usable UVs ({shown}{more})" if self.skipped else "no bound prims"


def texels_per_uv(texels_per_metre: float, metres_per_uv: float) -> int:
    """ceil(D x metres per UV unit): texels per UV unit a density of ``texels_per_metre`` needs (at least 1).

    A relative 1e-9 is forgiven so that an exact product (512 x 0.25 = 128) that
    floating point lands a hair above does not round up to 129.
    """
    return max(1, math.ceil(texels_per_metre * metres_per_uv * (1 - 1e-9)))


def open_stage_for(asset) -> object | None:
    """The USD stage of ``asset`` (a path, or an open ``Usd.Stage``: its private
    :func:`~.usd_stage.stage_view`), or None when it is not a USD file (plain ``.mtlx``)."""
    if is_stage(asset):
        return stage_view(asset)
    if os.path.splitext(os.fspath(asset))[1].lower() not in USD_EXTENSIONS:
        return None

    return open_stage(os.path.abspath(os.fspath(asset)))


def surface_density(stage, prim_paths) -> SurfaceDensity:
    """Measure every prim of ``prim_paths`` (gprims or GeomSubsets) on ``stage`` (see the module docstring)."""
    from pxr import UsdGeom

    out = SurfaceDensity(meters_per_unit=UsdGeom.GetStageMetersPerUnit(stage),
                         unit_authored=UsdGeom.StageHasAuthoredMetersPerUnit(stage))
    if not prim_paths:
        out.note = "no prims are bound to this material"
        return out
    for path in prim_paths:
        result = mesh_density(stage, path)
        if isinstance(result, str):
            out.skipped.append((str(path), result))
        else:
            out.meshes.append(result)
    return out


def mesh_density(stage, path) -> MeshDensity | str:
    """The areas of the mesh (or GeomSubset of a mesh) at ``path``, or a reason why it cannot be measured."""
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
    points = _get(mesh.GetPointsAttr())
    counts = _get(mesh.GetFaceVertexCountsAttr())
    indices = _get(mesh.GetFaceVertexIndicesAttr())
    if points is None or counts is None or indices is None or len(points) == 0:
        return "mesh has no points or faces"
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if counts.sum() != len(indices) or (len(indices) and (indices.min() < 0 or indices.max() >= len(points))):
        return "malformed topology (faceVertexCounts/faceVertexIndices do not match the points)"
    uv, how = _texcoords(mesh)
    if uv is None:
        return how
    if how == "faceVarying":
        if len(uv) != len(indices):
            return f"texture coordinates: {len(uv)} faceVarying values for {len(indices)} face-vertices"
    elif len(uv) != len(points):
        return f"texture coordinates: {len(uv)} {how} values for {len(points)} points"
    keep = np.ones(len(counts), dtype=bool)
    if faces is not None:
        keep[:] = False
        keep[faces[(faces >= 0) & (faces < len(counts))]] = True
    holes = _get(mesh.GetHoleIndicesAttr())
    if holes is not None and len(holes):
        holes = np.asarray(holes, dtype=np.int64)
        keep[holes[(holes >= 0) & (holes < len(counts))]] = False
    tris = _fan_triangles(counts, keep)  # [T, 3] face-vertex positions
    if len(tris) == 0:
        return "no polygons" + (" in the subset" if faces is not None else "")
    xf = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    world = np.hstack([points, np.ones((len(points), 1))]) @ xf
    world = world[:, :3] / world[:, 3:4]
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    corners = world[indices[tris]]  # [T, 3, 3]
    world_area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                                      axis=1).sum() * mpu * mpu
    t = uv[tris] if how == "faceVarying" else uv[indices[tris]]  # [T, 3, 2]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    if not (uv_area > 0 and math.isfinite(uv_area)):
        return "texture coordinates span no area"
    if not (world_area > 0 and math.isfinite(world_area)):
        return "mesh has no surface area"
    return MeshDensity(str(path), float(world_area), float(uv_area))


def _get(attr):
    """The attribute's value at the default time, else at its earliest time sample (animated meshes)."""
    from pxr import Usd

    value = attr.Get(Usd.TimeCode.Default())
    return attr.Get(Usd.TimeCode.EarliestTime()) if value is None else value


def uv_primvar(mesh):
    """The primvar a mesh's UV layout is read from (the UV set every tool here uses): ``st`` when it has a
    value, else the first ``texCoord2[fdh][]`` primvar with one; None when there is none."""
    from pxr import Sdf, UsdGeom

    api = UsdGeom.PrimvarsAPI(mesh)
    pv = api.GetPrimvar("st")
    if not (pv and pv.HasValue()):
        uv_types = (Sdf.ValueTypeNames.TexCoord2fArray, Sdf.ValueTypeNames.TexCoord2dArray,
                    Sdf.ValueTypeNames.TexCoord2hArray)
        pv = next((p for p in api.GetPrimvarsWithValues() if p.GetTypeName() in uv_types), None)
    return pv


def _texcoords(mesh):
    """(flattened [N, 2] float64 texture coordinates, interpolation) of :func:`uv_primvar`, or (None, why not)."""
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


def _fan_triangles(counts: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """[T, 3] face-vertex positions of the fan triangles (0, k, k+1) of every kept polygon."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_tris = np.where(keep, np.maximum(counts - 2, 0), 0)
    total = int(n_tris.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64)
    first = np.repeat(starts, n_tris)
    offsets = np.repeat(np.cumsum(n_tris) - n_tris, n_tris)
    k = np.arange(total, dtype=np.int64) - offsets + 1  # 1 .. count-2 within each polygon
    return np.stack([first, first + k, first + k + 1], axis=1)
