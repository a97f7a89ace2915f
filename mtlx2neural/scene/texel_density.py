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

from mtlx2neural.scene.mesh_reading import fan_triangles, object_to_world, read_topology
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
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
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
    """The areas of the mesh (or GeomSubset of a mesh) at ``path``, or a reason why it cannot be measured
    (hole faces left out)."""
    topo = read_topology(stage, path)
    if isinstance(topo, str):
        return topo
    if topo.uv is None:
        return topo.uv_how
    if (why := topo.uv_count_error()) is not None:
        return why
    tris = fan_triangles(topo.counts, topo.keep & ~topo.holes)  # [T, 3] face-vertex positions
    if len(tris) == 0:
        return "no polygons" + (" in the subset" if topo.subset else "")
    # Local: pxr loads its plugins on import; only a stage's meshes get here.
    from pxr import UsdGeom

    points, indices = topo.points, topo.indices
    xf = object_to_world(stage, path)
    world = np.hstack([points, np.ones((len(points), 1))]) @ xf
    world = world[:, :3] / world[:, 3:4]
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    corners = world[indices[tris]]  # [T, 3, 3]
    world_area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                                      axis=1).sum() * mpu * mpu
    t = topo.uv_corners(tris)  # [T, 3, 2]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    if not (uv_area > 0 and math.isfinite(uv_area)):
        return "texture coordinates span no area"
    if not (world_area > 0 and math.isfinite(world_area)):
        return "mesh has no surface area"
    return MeshDensity(str(path), float(world_area), float(uv_area))
