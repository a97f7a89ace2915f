"""Geometry in UV space: the bound meshes rasterised into their UV layout, per texel.

A material's graph may read the surface it lies on (``position``, ``normal``, ``tangent``,
``bitangent``, ``geomcolor``, ``geompropvalue``). Its neural form is a function of uv only, so
these inputs are baked from the geometry the material is bound to: every bound mesh is drawn
into the material's UV layout at the latent/parameter grid's resolution, and the graph reads the
maps at each uv sample (:meth:`GeometryMaps.sample`, bilinear).

Maps (``GeometryMaps.maps``, each ``[C, H, W]`` float32, row 0 at the *top* of UV space (v = 1),
texel (r, c) centred at uv ((c + 0.5) / W, 1 - (r + 0.5) / H), as the parameter stack's):

- ``position:object`` (3): the mesh's ``points`` as authored, in stage units (``metersPerUnit``
  not applied; MaterialX positions are in scene units);
- ``position:world`` (3): the same through the prim's local-to-world transform at the default
  time, stage units;
- ``normal:object`` / ``normal:world`` (3, unit): the authored ``normals`` when the mesh has them
  (vertex, varying or faceVarying), else the triangle's geometric normal (right-handed winding,
  flipped for ``orientation = leftHanded``); world normals through the inverse transpose;
- ``tangent:object`` / ``tangent:world`` (3, unit): dP/du of the triangle (from its UV
  derivatives) made orthogonal to the normal; ``bitangent:*`` = normal x tangent, signed so that
  it points along dP/dv (mirrored UVs flip it);
- ``primvar:NAME`` (1-4): each requested primvar, interpolated like the UVs (constant, uniform,
  vertex/varying, faceVarying); ``geomcolor`` reads ``primvar:displayColor`` (and
  ``displayOpacity`` as alpha);
- ``transform:object_to_world`` (16, :data:`TRANSFORM_KEY`; not a map: :meth:`GeometryMaps.sample`
  gives it per uv from the texel's owner): the local-to-world matrix of the prim that drew the texel
  (nearest texel, never blended), 4x4 row by row in USD's row-vector convention (world = [p, 1] M),
  for the object/world ``transform*`` nodes. Where two bound prims with different transforms
  overlap in UV, the first in binding order owns the texel; when the material reads the matrix
  (``transforms=True``) a warning names both prims.

Coverage and fill: a texel belongs to a triangle when its centre lies inside it (a top-left rule
on shared edges, so an edge texel is drawn once). Several meshes bound to one material share the
layout: where they overlap (instanced assets) the first prim in binding order wins. Two triangles
of *one* mesh covering the same texel are overlapping UVs: a warning names the prim. Texels no
triangle covers take the value of the nearest covered texel (Euclidean distance in texels, not
wrapped), so bilinear lookups and MIP levels near UV-shell borders never mix in empty texels.
UVs outside [0, 1] wrap (the layout is periodic, as the latents are). A prim without usable UVs
is left out with a warning naming it; when no bound prim can be drawn, the unit sphere
(:func:`sphere_maps`) stands in, with a warning.

The sphere default (``.mtlx`` input, no mesh): the unit sphere at the origin, object space =
world space, with the renderer's spherical layout (:class:`mtlx2neural.render.geometry.Sphere`):
u = 0.5 + atan2(x, z) / 2pi, v = acos(-y) / pi, tangent along dP/du, bitangent = normal x tangent.
It has no primvars: ``geompropvalue`` gives its default and ``geomcolor`` 1.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import torch

from mtlx2neural.imaging.grid_lookup import bilinear_periodic
from mtlx2neural.scene.mesh_reading import mesh_triangles, object_to_world, uv_primvar

FRAME_KEYS = tuple(f"{kind}:{space}" for kind in ("position", "normal", "tangent", "bitangent")
                   for space in ("object", "world"))
SPHERE = "unit sphere (default mesh)"
TRANSFORM_KEY = "transform:object_to_world"


@dataclass
class GeometryMaps:
    """Per-texel geometry of a material's UV layout (module docstring for keys, spaces, units)."""

    resolution: tuple[int, int]
    """(H, W) texels over UV [0, 1]^2."""
    maps: dict[str, torch.Tensor]
    """key -> [C, H, W] float32, row 0 at v = 1."""
    covered: torch.Tensor
    """[H, W] bool: texels some triangle covers (the others are filled from the nearest one)."""
    prims: list[str] = field(default_factory=list)
    """The prims drawn, or [:data:`SPHERE`]."""
    warnings: list[str] = field(default_factory=list)
    owner: torch.Tensor | None = None
    """[H, W] int64: per texel, the index into :attr:`transforms` of the prim that drew it (filled
    like the maps); None: every texel is the identity's."""
    transforms: torch.Tensor | None = None
    """[P, 4, 4] float32 local-to-world matrices of :attr:`prims` (row-vector convention); None: identity."""
    _moved: dict = field(default_factory=dict, repr=False, compare=False)

    def sample(self, uv: torch.Tensor, keys: Iterable[str] | None = None) -> dict[str, torch.Tensor]:
        """Bilinear (periodic) lookup of ``keys`` (default all) at ``uv`` [N,2]: ``{key: [N, C]}``
        in ``uv``'s dtype and device. Exact at texel centres."""
        out = {}
        for k in (self.maps if keys is None else keys):
            if k == TRANSFORM_KEY:
                out[k] = self.object_to_world(uv)
            elif k in self.maps:
                grid = self._moved.get((k, uv.device))
                if grid is None:  # one copy per device, not one transfer per batch
                    grid = self._moved[(k, uv.device)] = self.maps[k].to(uv.device)
                out[k] = bilinear_periodic(grid, uv).to(uv.dtype)
        return out


    def object_to_world(self, uv: torch.Tensor) -> torch.Tensor:
        """[N, 16] local-to-world matrices (row by row, row-vector convention) of the prims owning the
        texels ``uv`` [N, 2] falls in (periodic, nearest texel: matrices of two prims are never blended)."""
        n = uv.shape[0]
        if self.owner is None or self.transforms is None:
            return torch.eye(4, dtype=uv.dtype, device=uv.device).reshape(1, 16).expand(n, 16)
        h, w = self.resolution
        col = torch.floor(uv[:, 0].detach() * w).long().remainder(w)
        row = (h - 1) - torch.floor(uv[:, 1].detach() * h).long().remainder(h)  # row 0 at v = 1
        idx = self.owner.to(uv.device)[row, col]
        return self.transforms.to(uv.device, uv.dtype)[idx].reshape(n, 16)


# ----------------------------------------------------------------------------- the sphere default


def sphere_maps(resolution: tuple[int, int]) -> GeometryMaps:
    """The unit sphere's geometry at the texel centres of an (H, W) grid (module docstring)."""
    h, w = resolution
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)  # [H, W], row 0 at v = 1
    phi = (uu - 0.5) * 2 * math.pi
    theta = vv * math.pi
    r = np.sin(theta)
    p = np.stack([r * np.sin(phi), -np.cos(theta), r * np.cos(phi)], 0)
    t = np.stack([np.cos(phi), np.zeros_like(phi), -np.sin(phi)], 0)
    b = np.cross(p, t, axis=0)
    maps = {}
    for kind, value in (("position", p), ("normal", p), ("tangent", t), ("bitangent", b)):
        for space in ("object", "world"):
            maps[f"{kind}:{space}"] = torch.from_numpy(value.astype(np.float32))
    return GeometryMaps((h, w), maps, torch.ones(h, w, dtype=torch.bool), [SPHERE])


# ----------------------------------------------------------------------------- meshes


def _normalise(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


class _Canvas:
    """The shared UV layout the bound meshes are drawn into."""

    def __init__(self, resolution):
        self.h, self.w = resolution
        self.values: dict[str, np.ndarray] = {}
        self.covered = np.zeros((self.h, self.w), dtype=bool)
        self.owner = np.zeros((self.h, self.w), dtype=np.int64)
        self.under: set[int] = set()
        """The owners of texels the last :meth:`draw` found already drawn (other prims it overlaps)."""

    def draw(self, uv: np.ndarray, corners: dict[str, np.ndarray], index: int = 0) -> int:
        """Draw triangles (``uv`` [T, 3, 2]; ``corners`` key -> [T, 3, C]) of prim number ``index`` where
        nothing was drawn yet (the lowest-numbered triangle keeps a texel); returns the number of texels
        two of these triangles both cover (overlapping UVs). Vectorised over batches of triangles of
        similar size."""
        h, w = self.h, self.w
        self.under = set()
        tri, row, col, wts = _hits(uv[..., 0] * w - 0.5, uv[..., 1] * h - 0.5)  # texel-centre coordinates
        if len(tri) == 0:
            return 0
        texel = (h - 1 - np.mod(row, h)) * w + np.mod(col, w)  # the maps' row 0 is v = 1
        drawn_before = self.covered.ravel()[texel]
        self.under = set(np.unique(self.owner.ravel()[texel[drawn_before]]).tolist())
        count = np.bincount(texel, minlength=h * w)
        overlap = int((count > 1).sum())
        best = np.full(h * w, len(uv), dtype=np.int64)
        np.minimum.at(best, texel, tri)  # the first triangle wins a texel
        keep = (best[texel] == tri) & ~self.covered.ravel()[texel]
        tri, texel, wts = tri[keep], texel[keep], wts[keep]
        keys = list(corners)
        widths = [corners[k].shape[-1] for k in keys]
        table = np.concatenate([np.broadcast_to(corners[k], (len(uv), 3, c)) for k, c in zip(keys, widths)],
                               axis=2).astype(np.float32)  # [T, 3, all channels]: one gather per hit
        vals = np.empty((len(tri), table.shape[-1]), dtype=np.float32)
        for a in range(0, len(tri), 1 << 18):  # chunks bound the [hits, 3, channels] temporary
            b = a + (1 << 18)
            vals[a:b] = np.einsum("nk,nkc->nc", wts[a:b].astype(np.float32), table[tri[a:b]])
        o = 0
        for key, c in zip(keys, widths):
            buf = self.values.get(key)
            if buf is None:
                buf = self.values[key] = np.zeros((h, w, c), dtype=np.float32)
            buf.reshape(h * w, c)[texel] = vals[:, o:o + c]
            o += c
        self.covered.ravel()[texel] = True
        self.owner.ravel()[texel] = index
        return overlap

    def maps(self, prims, notes, transforms=None) -> GeometryMaps:
        """The drawn values with every uncovered texel filled from its nearest covered one
        (``transforms``: [P, 4, 4] local-to-world matrices of ``prims``)."""
        # Local: scipy.ndimage is needed only here, once per drawn layout; importing it at the top
        # would load it for every command, --help included.
        from scipy import ndimage

        if self.covered.any() and not self.covered.all():
            _, (ri, ci) = ndimage.distance_transform_edt(~self.covered, return_indices=True)
            for key, buf in self.values.items():
                self.values[key] = buf[ri, ci]
            self.owner = self.owner[ri, ci]
        maps = {}
        for key, buf in self.values.items():
            if key.split(":")[0] in ("normal", "tangent", "bitangent"):
                buf = _normalise(buf)
            maps[key] = torch.from_numpy(np.ascontiguousarray(buf.transpose(2, 0, 1)).astype(np.float32))
        xf = None if transforms is None else torch.from_numpy(np.asarray(transforms, dtype=np.float32))
        return GeometryMaps((self.h, self.w), maps, torch.from_numpy(self.covered.copy()), list(prims), notes,
                            torch.from_numpy(self.owner.copy()), xf)


BATCH_TEXELS = 1 << 21  # candidate texel centres tested per batch (bounds memory to ~100 MB)


def _hits(px: np.ndarray, py: np.ndarray):
    """Every (triangle, row, column, barycentric weights [3]) with the texel centre (column, row)
    inside the triangle (``px``, ``py`` [T, 3]: corners in texel-centre units, rows from v = 0;
    rows and columns unwrapped). On a shared edge a top-left rule keeps the centre in one triangle:
    each edge's function is computed from its endpoints in a canonical order, so both triangles
    see the same number with opposite signs, and exactly one of them owns the zero."""
    area = (px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0])
    x0, x1 = np.ceil(px.min(1)), np.floor(px.max(1))
    y0, y1 = np.ceil(py.min(1)), np.floor(py.max(1))
    ok = np.isfinite(area) & (area != 0) & (x1 >= x0) & (y1 >= y0)
    t = np.nonzero(ok)[0]
    nx, ny = (x1 - x0 + 1)[t].astype(np.int64), (y1 - y0 + 1)[t].astype(np.int64)
    # Jobs: (triangle, first row, rows); a triangle larger than a batch is cut into bands of rows.
    band = np.maximum(1, BATCH_TEXELS // np.maximum(nx, 1))
    parts = (ny + band - 1) // band
    jt = np.repeat(t, parts)
    k = np.arange(len(jt)) - np.repeat(np.cumsum(parts) - parts, parts)
    jy0 = y0[jt] + k * np.repeat(band, parts)
    jny = np.minimum(np.repeat(band, parts), y1[jt] - jy0 + 1).astype(np.int64)
    jnx = np.repeat(nx, parts)
    order = np.argsort(jnx * jny, kind="stable")
    out = [], [], [], []
    i = 0
    snx, sny = jnx[order].tolist(), jny[order].tolist()
    while i < len(order):
        j, bx, by = i + 1, snx[i], sny[i]
        while j < len(order) and (j - i + 1) * max(bx, snx[j]) * max(by, sny[j]) <= BATCH_TEXELS:
            bx, by = max(bx, snx[j]), max(by, sny[j])  # the batch's padded box stays within budget
            j += 1
        sel = order[i:j]
        i = j
        tri = jt[sel]
        gx = x0[tri][:, None, None] + np.arange(bx)[None, None, :]
        gy = jy0[sel][:, None, None] + np.arange(by)[None, :, None]
        valid = (np.arange(bx)[None, None, :] < jnx[sel][:, None, None]) & (
            np.arange(by)[None, :, None] < jny[sel][:, None, None])
        sign = np.sign(area[tri])[:, None, None]
        bary = []
        for c in range(3):  # the weight of corner c: the edge (d, e) opposite it
            d, e = (c + 1) % 3, (c + 2) % 3
            xd, yd, xe, ye = px[tri, d], py[tri, d], px[tri, e], py[tri, e]
            swap = (xd > xe) | ((xd == xe) & (yd > ye))
            ax, ay = np.where(swap, xe, xd)[:, None, None], np.where(swap, ye, yd)[:, None, None]
            bx_, by_ = np.where(swap, xd, xe)[:, None, None], np.where(swap, yd, ye)[:, None, None]
            f = ((bx_ - ax) * (gy - ay) - (by_ - ay) * (gx - ax)) * np.where(swap, -1.0, 1.0)[:, None, None] * sign
            dx, dy = (xe - xd) * sign[:, 0, 0], (ye - yd) * sign[:, 0, 0]
            owned = ((dy < 0) | ((dy == 0) & (dx > 0)))[:, None, None]
            f = np.where((f == 0) & ~owned, -1.0, f)
            bary.append(f / np.abs(area[tri])[:, None, None])
        inside = valid & (bary[0] >= 0) & (bary[1] >= 0) & (bary[2] >= 0)
        if not inside.any():
            continue
        n_idx, r_idx, c_idx = np.nonzero(inside)
        out[0].append(tri[n_idx])
        out[1].append(gy[n_idx, r_idx, 0].astype(np.int64))
        out[2].append(gx[n_idx, 0, c_idx].astype(np.int64))
        out[3].append(np.stack([b[inside] for b in bary], 1))
    if not out[0]:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return tuple(np.concatenate(o) for o in out)


def rasterise_meshes(stage, prim_paths: Iterable[str], resolution: tuple[int, int],
                     primvars: Iterable[str] = (), transforms_read: bool = False) -> GeometryMaps:
    """Draw every mesh (or GeomSubset) of ``prim_paths`` on ``stage`` into one (H, W) UV layout
    (module docstring: keys, spaces, units, overlaps, fill). ``primvars``: the primvar names the
    material reads (``displayColor`` for ``geomcolor``); ``transforms_read``: the material reads the
    object-to-world matrix, so prims with different transforms overlapping in UV are warned about. Warnings (also issued with
    :func:`warnings.warn`) name the prims with overlapping or missing UVs; when none can be drawn
    the unit sphere's maps are returned with a warning saying so."""
    canvas = _Canvas(resolution)
    drawn, notes, transforms = [], [], []
    primvars = list(dict.fromkeys(primvars))
    for path in prim_paths:
        found = mesh_triangles(stage, path, primvars)
        if isinstance(found, str):
            notes.append(f"{path}: {found}: left out of the geometry maps")
            continue
        tuv, corners = found
        xf = object_to_world(stage, path)
        overlap = canvas.draw(tuv, corners, len(drawn))
        differ = [drawn[k] for k in sorted(canvas.under) if not np.allclose(transforms[k], xf, rtol=0, atol=1e-9)]
        if differ and transforms_read:
            notes.append(f"{path}: overlaps {', '.join(differ)} in UV with a different object-to-world transform: "
                         f"the first bound prim's geometry and transform are used there (object/world "
                         f"transform* nodes included)")
        drawn.append(str(path))
        transforms.append(xf)
        if overlap:
            notes.append(f"{path}: overlapping UVs ({overlap} texels covered more than once at "
                         f"{resolution[1]}x{resolution[0]}): the first triangle's geometry is used there")
        missing = [p for p in primvars if f"primvar:{p}" not in corners and p != "displayOpacity"]  # alpha: optional
        if missing:
            notes.append(f"{path}: no primvar {', '.join(missing)}: the node's default is used")
    if not drawn or not canvas.covered.any():
        notes.append(f"no bound mesh could be drawn into the UV layout ({', '.join(map(str, prim_paths)) or 'none'})"
                     f": the unit sphere (the default mesh) stands in")
        out = sphere_maps(resolution)
        out.warnings = notes
    else:
        out = canvas.maps(drawn, notes, transforms)
    for n in notes:
        warnings.warn(n, stacklevel=2)
    return out


class GeometrySource:
    """Where a material's geometric inputs come from: bound meshes of a USD stage, or the sphere.

    :meth:`maps` rasterises (and caches, per resolution) lazily, so a graph that never asks
    costs nothing."""

    def __init__(self, stage_file: str | None = None, prims: Iterable[str] = (), primvars: Iterable[str] = (),
                 transforms: bool = False):
        self.stage_file = stage_file
        self.prims = [str(p) for p in prims]
        self.primvars = list(primvars)
        self.transforms = transforms
        """Whether the material reads the object-to-world matrix (``transform*`` between object and world)."""
        self._cache: dict[tuple[int, int], GeometryMaps] = {}
        self._stage = None
        self.resolution: tuple[int, int] = (256, 256)
        """The grid :meth:`current` draws at: the parameter grid's, set by whoever builds it."""

    @property
    def is_sphere(self) -> bool:
        return not (self.stage_file and self.prims)

    def describe(self) -> str:
        """``mesh prims A, B`` or the sphere default, in a phrase."""
        return SPHERE if self.is_sphere else f"mesh prims {', '.join(self.prims)}"

    def digest(self) -> str:
        """Hex sha256 of the mesh data the maps are drawn from (:func:`~mtlx2neural.scene.mesh_digest.mesh_digest`:
        points, topology, UVs, normals, the primvars read, transforms); ``"sphere"`` for the default mesh."""
        if self.is_sphere:
            return "sphere"
        # Local: mesh_digest reads the stage through pxr, which a sphere never needs.
        from mtlx2neural.scene.mesh_digest import mesh_digest

        return mesh_digest(self.stage(), self.prims, self.primvars)

    def common_transform(self) -> torch.Tensor | None:
        """[16] the object-to-world matrix (row by row, row-vector convention) every bound mesh shares
        (the identity for the sphere), or None when they differ (then it is read per texel)."""
        if self.is_sphere:
            return torch.eye(4).reshape(16)
        # Local: pxr loads its plugins on import; only real meshes need it.
        from pxr import UsdGeom

        found = []
        for path in self.prims:
            prim = self.stage().GetPrimAtPath(path)
            if prim and (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.Subset)):
                found.append(object_to_world(self.stage(), path))
        if not found or any(not np.allclose(m, found[0], rtol=0, atol=1e-9) for m in found[1:]):
            return None
        return torch.from_numpy(found[0].astype(np.float32)).reshape(16)

    def _meshes(self):
        """(bound prim path, its UsdGeom.Mesh or None) for each bound prim; a GeomSubset gives its mesh."""
        # Local: pxr loads its plugins on import; only real meshes need it.
        from pxr import UsdGeom

        for path in self.prims:
            prim = self.stage().GetPrimAtPath(path)
            if prim and prim.IsA(UsdGeom.Subset):
                prim = prim.GetParent()
            yield path, (UsdGeom.Mesh(prim) if prim and prim.IsA(UsdGeom.Mesh) else None)

    def uv_sets(self) -> dict[str, str | None]:
        """{bound prim: the primvar its UV layout is drawn from (``st``, else its first texCoord2 primvar;
        None: no UVs)}; empty for the sphere (one layout, no primvars)."""
        if self.is_sphere:
            return {}
        out = {}
        for path, mesh in self._meshes():
            pv = uv_primvar(mesh) if mesh else None
            out[path] = None if pv is None else str(pv.GetPrimvarName())
        return out

    def primvar_names(self) -> dict[str, set[str]]:
        """{bound prim: the names of its primvars that have a value} (a GeomSubset's are its mesh's);
        empty for the sphere, which has none."""
        if self.is_sphere:
            return {}
        # Local: pxr loads its plugins on import; only real meshes need it.
        from pxr import UsdGeom

        return {path: {str(p.GetPrimvarName()) for p in UsdGeom.PrimvarsAPI(mesh).GetPrimvarsWithValues()}
                if mesh else set() for path, mesh in self._meshes()}

    def stage(self):
        """The USD stage of :attr:`stage_file` (opened once)."""
        # Local: opening a stage pulls in pxr's file format plugins; a sphere never needs them.
        from mtlx2neural.scene.usd_stage import open_stage

        if self._stage is None:
            self._stage = open_stage(self.stage_file)
        return self._stage

    def maps(self, resolution: tuple[int, int]) -> GeometryMaps:
        """The maps at (H, W) (cached)."""
        key = (int(resolution[0]), int(resolution[1]))
        if key not in self._cache:
            if self.is_sphere:
                self._cache[key] = sphere_maps(key)
            else:
                self._cache[key] = rasterise_meshes(self.stage(), self.prims, key, self.primvars, self.transforms)
        return self._cache[key]

    def current(self) -> GeometryMaps:
        return self.maps(self.resolution)
