"""Geometry for evaluation renders: perspective and orthographic cameras, an analytic sphere and
plane, and OBJ meshes.

Conventions (all torch float32, world units as the geometry defines them):

- World space is right-handed with **y up**.
- :class:`Camera` is a perspective pinhole that looks at the centre of the
  geometry's bounding sphere from ``azimuth``/``elevation`` (degrees; azimuth 0
  looks from +z towards -z, 90 from +x, elevation 90 from straight above) at
  ``distance`` bounding-sphere radii (> 1: the camera is outside the object), with
  a full vertical field of view ``fov`` (degrees). Images are square, row 0 at the
  top; each pixel's ray passes through a uniformly jittered point of the pixel.
- :class:`PinholeCamera` is the general perspective pinhole: an eye ``position``, a unit view
  direction ``forward``, an image ``up`` and a full vertical field of view ``fov`` (degrees), all
  in world space; :meth:`PinholeCamera.from_matrix` reads a camera-to-world matrix (row-vector
  convention, as USD: the camera looks along its local -z with +y up, the translation in the
  last row) and :func:`framing_camera` frames a bounding sphere from an azimuth/elevation.
- :class:`OrthographicCamera` looks from the same ``azimuth``/``elevation`` with
  parallel rays: the image spans +-``half_width`` bounding-sphere radii (1.1: the
  unit sphere with a margin, the evaluation views of ``renderer.render``); each
  ray starts 2 radii in front of the centre, outside the bounding sphere.
- :meth:`intersect` returns a :class:`Hits` for every ray: ``mask`` (hit or not),
  ``t`` (distance along the unit ray), ``position``, the orthonormal right-handed
  shading frame ``tangent``/``bitangent``/``normal`` (tangent = the surface's
  dP/du direction made orthogonal to the shading normal, bitangent = n x t,
  flipped where the uv map is mirrored so that it follows +v), ``uv``, the uv
  density ``dpdu``/``dpdv`` (|dP/du|, |dP/dv| in world units per uv unit) and
  ``cos`` = |cos| between the ray and the geometric normal. Misses hold zeros.
- Level of detail (:func:`ray_cone_lod`): every ray carries a cone of width
  ``width + spread * t`` at distance ``t``. A pinhole's cone has width 0 at the
  eye and spread ``2 tan(fov/2) / res`` (one pixel's angle); an orthographic
  beam has the constant width of one pixel, ``2 half_width radius / res``, and
  spread 0. The footprint on the surface is that width / ``cos``, in uv units
  footprint/|dP/du| and footprint/|dP/dv|, in texels of the finest level those
  times (w, h). The footprint is an ellipse with axes ``width`` (across the
  slope) and ``width / cos`` (along it); lod = log2 of the geometric mean of its
  axes in texels, as the paper's isotropic footprint (0.5 log2 of the product),
  clamped at 0: ``log2(width / sqrt(cos) * sqrt(w h / (dpdu dpdv)))``.

Surfaces:

- :class:`Sphere`: the unit sphere at the origin; u = 0.5 + atan2(x, z) / 2pi
  around the y axis, v = acos(-y) / pi from the south pole; the tangent points
  along increasing u.
- :class:`Plane`: the square [-1, 1]^2 in the xz plane (y = 0, normal +y), uv over
  [0, 1]^2 repeated ``tiles`` times; u along +x, v along -z. Two-sided: seen from
  below, the normal and bitangent flip.
- :class:`Mesh` (:func:`load_obj`): triangles with per-corner uv and smooth
  normals (the file's vn, else area-weighted vertex normals); per-vertex tangents
  accumulate the area-weighted dP/du of the adjacent triangles (split at uv seams,
  in the spirit of MikkTSpace). It is rasterised, not ray traced: each triangle is
  projected into the camera, every pixel of its screen bounding box is tested
  with an exact ray/triangle test against that pixel's ray, and a z-buffer keeps
  the nearest hit. This needs the camera's projection (``Rays.project``, from
  any camera) and is brute force over triangles (no BVH), chunked to bound
  memory. A triangle wholly behind a pinhole's eye is skipped; one that straddles
  the eye's plane (a stage camera inside a room) tests every pixel of the image,
  the exact ray test deciding.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mtlx2neural.errors import InputError

CANDIDATE_CHUNK = 1 << 21  # (triangle, pixel) pairs tested at once by the mesh rasteriser


def _view_basis(azimuth: float, elevation: float):
    """(d, right, up): the unit vector from the target towards a camera at ``azimuth``/``elevation``
    (degrees), and the image axes (right = world_up x d, up = d x right; world up is +y, or -z when
    looking straight down or up)."""
    az, el = math.radians(azimuth), math.radians(elevation)
    d = torch.tensor([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
    world_up = torch.tensor([0.0, 1.0, 0.0]) if abs(d[1]) < 0.999 else torch.tensor([0.0, 0.0, -1.0])
    right = F.normalize(torch.linalg.cross(world_up, d), dim=0)
    return d, right, torch.linalg.cross(d, right)


def _jittered_pixels(res: int, generator: torch.Generator | None):
    """Image-plane coordinates (x, y) in [-1, 1] of one uniformly jittered point per pixel, row-major,
    row 0 at the top (y = 1)."""
    ij = torch.stack(torch.meshgrid(torch.arange(res), torch.arange(res), indexing="ij"), -1)
    ij = ij.reshape(-1, 2).float() + torch.rand(res * res, 2, generator=generator)
    return ij[:, 1] / res * 2 - 1, 1 - ij[:, 0] / res * 2


@dataclass(frozen=True)
class Camera:
    """Perspective pinhole looking at the bounding-sphere centre (see the module docstring)."""

    azimuth: float = 0.0
    elevation: float = 20.0
    distance: float = 4.0
    fov: float = 30.0

    def basis(self):
        """(d, right, up): unit vector from the target to the camera, and the image axes."""
        return _view_basis(self.azimuth, self.elevation)

    def rays(self, res: int, centre, radius: float, generator: torch.Generator | None = None) -> Rays:
        """One ray per pixel (row-major, row 0 at the top) through a jittered point of the pixel, all
        from the eye: cones of width 0 at the eye and spread ``2 tan(fov/2) / res`` radians."""
        if self.distance <= 1.0:
            raise ValueError(f"camera distance {self.distance} must exceed 1 bounding-sphere radius")
        d, right, up = self.basis()
        origin = torch.as_tensor(centre, dtype=torch.float32) + d * (self.distance * radius)
        return _pinhole_rays(origin, d, right, up, math.tan(math.radians(self.fov) / 2), res, generator)


def _pinhole_rays(origin, d, right, up, tan_half: float, res: int, generator) -> Rays:
    """A pinhole's rays from ``origin`` along ``-d`` (``d``, ``right``, ``up``: orthonormal, world),
    the image spanning +-``tan_half`` on the plane at distance 1 in both axes (square)."""
    x, y = _jittered_pixels(res, generator)
    dirs = F.normalize(-d + (x * tan_half)[:, None] * right + (y * tan_half)[:, None] * up, dim=-1)

    def project(points: torch.Tensor):
        rel = points - origin
        z = -(rel @ d)
        zs = torch.where(z > 0, z, torch.ones_like(z))
        return ((rel @ right) / zs / tan_half + 1) / 2 * res, (1 - (rel @ up) / zs / tan_half) / 2 * res, z

    return Rays(origin, dirs, 2 * tan_half / res, 0.0, project)


@dataclass(frozen=True)
class PinholeCamera:
    """A perspective pinhole anywhere (module docstring): eye ``position``, view direction ``forward``
    and image ``up`` (world; normalised here, ``up`` made orthogonal to ``forward``), full vertical
    field of view ``fov`` in degrees; the image is square. Unlike :class:`Camera` it ignores the
    geometry's bounds: it sees what a stage's camera sees."""

    position: tuple
    forward: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = 30.0

    @classmethod
    def from_matrix(cls, to_world, fov: float) -> PinholeCamera:
        """The camera of a 4x4 camera-to-world matrix in the row-vector convention (USD's Gf.Matrix4d:
        world = [x, y, z, 1] @ M): it looks along its local -z (row 2 negated), +y (row 1) is image
        up, the eye is row 3; scale and shear only change lengths, which are normalised away."""
        m = np.asarray(to_world, dtype=np.float64).reshape(4, 4)
        return cls(tuple(m[3, :3] / m[3, 3]), tuple(-m[2, :3]), tuple(m[1, :3]), float(fov))

    def basis(self):
        """(d, right, up): unit vector from the view towards the eye (-forward), and the image axes."""
        d = -F.normalize(torch.tensor(self.forward, dtype=torch.float32), dim=0)
        up = torch.tensor(self.up, dtype=torch.float32)
        right = torch.linalg.cross(up, d)
        if float(right.norm()) < 1e-6:  # up parallel to the view: any perpendicular will do
            right = torch.linalg.cross(torch.tensor([0.0, 0.0, -1.0]) if abs(float(d[1])) > 0.9
                                       else torch.tensor([0.0, 1.0, 0.0]), d)
        right = F.normalize(right, dim=0)
        return d, right, torch.linalg.cross(d, right)

    def rays(self, res: int, centre=None, radius: float | None = None,
             generator: torch.Generator | None = None) -> Rays:
        """One ray per pixel (row-major, row 0 at the top) from ``position`` through a jittered point of
        the pixel: cones of width 0 at the eye and spread ``2 tan(fov/2) / res`` radians. ``centre`` and
        ``radius`` (the geometry's bounds, which :func:`~mtlx2neural.render.renderer.render_scene`
        passes every camera) are ignored."""
        if not 0.0 < self.fov < 180.0:
            raise ValueError(f"field of view {self.fov} degrees must lie in (0, 180)")
        d, right, up = self.basis()
        origin = torch.tensor(self.position, dtype=torch.float32)
        return _pinhole_rays(origin, d, right, up, math.tan(math.radians(self.fov) / 2), res, generator)


def framing_camera(centre, radius: float, azimuth: float = 30.0, elevation: float = 25.0,
                   fov: float = 30.0, margin: float = 1.1) -> PinholeCamera:
    """A :class:`PinholeCamera` looking at ``centre`` from ``azimuth``/``elevation`` (degrees, as
    :class:`Camera`) far enough for the sphere of ``radius`` around it (world units) to fill the
    image with ``margin``: distance ``margin * radius / sin(fov / 2)``."""
    d, _, up = _view_basis(azimuth, elevation)
    dist = margin * max(float(radius), 1e-6) / math.sin(math.radians(fov) / 2)
    c = torch.as_tensor(centre, dtype=torch.float32)
    return PinholeCamera(tuple((c + d * dist).tolist()), tuple((-d).tolist()), tuple(up.tolist()), fov)


@dataclass(frozen=True)
class OrthographicCamera:
    """Parallel projection looking at the bounding-sphere centre (see the module docstring): the
    image spans +-``half_width`` bounding radii around the centre in both axes."""

    azimuth: float = 0.0
    elevation: float = 20.0
    half_width: float = 1.1

    def basis(self):
        """(d, right, up): unit vector from the target towards the camera, and the image axes."""
        return _view_basis(self.azimuth, self.elevation)

    def rays(self, res: int, centre, radius: float, generator: torch.Generator | None = None) -> Rays:
        """One ray per pixel (row-major, row 0 at the top) through a jittered point of the pixel, all
        along ``-d``; each starts on the plane 2 radii in front of the centre (outside the bounding
        sphere). Beams of constant width ``2 half_width radius / res`` (world units) and spread 0."""
        if self.half_width <= 0:
            raise ValueError(f"orthographic half width {self.half_width} must be positive")
        d, right, up = self.basis()
        c = torch.as_tensor(centre, dtype=torch.float32)
        span = self.half_width * radius
        x, y = _jittered_pixels(res, generator)
        origins = c + d * (2 * radius) + (x * span)[:, None] * right + (y * span)[:, None] * up
        dirs = (-d).expand(res * res, 3).contiguous()

        def project(points: torch.Tensor):
            rel = points - c
            return ((rel @ right) / span + 1) / 2 * res, (1 - (rel @ up) / span) / 2 * res, 2 * radius - rel @ d

        return Rays(origins, dirs, 0.0, 2 * span / res, project)


@dataclass
class Rays:
    """Primary rays, one per pixel of a square ``res`` x ``res`` image (row-major).

    ``origin``: [3] shared by every ray (a pinhole) or [P,3] one per ray (orthographic); ``dirs`` [P,3]
    unit. Each ray carries a cone (module docstring, Level of detail) of ``width`` world units at the
    origin that grows by ``spread`` radians per unit of distance. ``project`` maps world points [V,3]
    to (column, row, depth) [V] each: pixel coordinates of the point (0..res across the image) and its
    distance in front of the rays' origins (<= 0: behind), for rasterising meshes."""

    origin: torch.Tensor
    dirs: torch.Tensor
    spread: float
    width: float = 0.0
    project: Callable | None = None
    tmin: torch.Tensor | None = None
    """[P] the nearest distance a hit may have (None: 0): a ray continued beyond a cut-out's hit."""

    def nearest(self, index: torch.Tensor | None = None) -> torch.Tensor | float:
        """The smallest hit distance of the rays ``index`` (all rays when None): ``tmin``, or 0."""
        if self.tmin is None:
            return 0.0
        return self.tmin if index is None else self.tmin[index]

    def origins(self, index: torch.Tensor) -> torch.Tensor:
        """The origins of the rays ``index`` ([3] when they share one, else [len(index), 3])."""
        return self.origin if self.origin.dim() == 1 else self.origin[index]


@dataclass
class Hits:
    """Per-ray surface data (see the module docstring); every field has the rays' leading size P."""

    mask: torch.Tensor
    t: torch.Tensor
    position: torch.Tensor
    tangent: torch.Tensor
    bitangent: torch.Tensor
    normal: torch.Tensor
    uv: torch.Tensor
    dpdu: torch.Tensor
    dpdv: torch.Tensor
    cos: torch.Tensor
    material: torch.Tensor | None = None
    """[P] int64: the hit triangle's material index (:attr:`Mesh.material_index`); None: material 0."""

    @staticmethod
    def empty(n: int) -> Hits:
        z = torch.zeros
        return Hits(z(n, dtype=torch.bool), z(n), z(n, 3), z(n, 3), z(n, 3), z(n, 3), z(n, 2), z(n), z(n), z(n),
                    z(n, dtype=torch.long))

    def to_local(self, w: torch.Tensor) -> torch.Tensor:
        """World directions [P,3] -> shading-frame coordinates (t, b, n)."""
        return torch.stack([(w * self.tangent).sum(-1), (w * self.bitangent).sum(-1),
                            (w * self.normal).sum(-1)], -1)

    def to_world(self, w: torch.Tensor) -> torch.Tensor:
        """Shading-frame coordinates [P,3] -> world directions (the inverse of :meth:`to_local`)."""
        return w[:, 0:1] * self.tangent + w[:, 1:2] * self.bitangent + w[:, 2:3] * self.normal


def ray_cone_lod(hits: Hits, spread: float, texels: tuple[int, int], width: float = 0.0) -> torch.Tensor:
    """Level of detail [P] = log2(footprint in finest-level texels), clamped to [0, 30].

    The cone's width at the hit is ``width + spread * t`` world units (``width`` at the ray's origin,
    ``spread`` radians: 0 and one pixel's angle for a pinhole, one pixel's size and 0 for an
    orthographic beam); divided by ``cos`` it is the footprint on the surface, divided by
    ``dpdu``/``dpdv`` and times the texel counts (h, w) it is in texels. Its two axes are the cone's
    width and that width / ``cos``; the level is log2 of their geometric mean in texels, the
    isotropic footprint of the paper's supplement (listing 1) and of the shaders'
    ``nmLodFromFootprint`` (module docstring)."""
    foot = (width + spread * hits.t) / hits.cos.clamp_min(1e-4).sqrt()
    h, w = texels
    texel_area = (w / hits.dpdu.clamp_min(1e-12)) * (h / hits.dpdv.clamp_min(1e-12))
    return torch.log2((foot * texel_area.sqrt()).clamp(1.0, 2.0 ** 30))


def _orthonormal(n: torch.Tensor, t: torch.Tensor, handed: torch.Tensor | None = None):
    """Gram-Schmidt ``t`` against unit ``n`` (any perpendicular where ``t`` is parallel); b = +-n x t."""
    t = t - n * (n * t).sum(-1, keepdim=True)
    alt = torch.where(n[:, :1].abs() < 0.9, torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([[0.0, 1.0, 0.0]]))
    alt = F.normalize(alt - n * (n * alt).sum(-1, keepdim=True), dim=-1)
    t = torch.where(t.norm(dim=-1, keepdim=True) > 1e-6, F.normalize(t, dim=-1), alt)
    b = torch.linalg.cross(n, t, dim=-1)
    return t, (b if handed is None else b * handed[:, None])


class Sphere:
    """The unit sphere at the origin (module docstring for its uv and frame)."""

    def bounds(self):
        return torch.zeros(3), 1.0

    def intersect(self, rays: Rays) -> Hits:
        o, d = rays.origin, rays.dirs
        b = (d * o).sum(-1)
        disc = b * b - ((o * o).sum(-1) - 1.0)
        near = rays.nearest()
        t = -b - disc.clamp_min(0).sqrt()
        t = torch.where(t > near, t, -b + disc.clamp_min(0).sqrt())  # beyond tmin: the far side
        mask = (disc > 0) & (t > near)
        p = o + t[:, None] * d
        n = F.normalize(p, dim=-1)
        u = 0.5 + torch.atan2(n[:, 0], n[:, 2]) / (2 * math.pi)
        v = torch.acos((-n[:, 1]).clamp(-1, 1)) / math.pi
        r_xz = torch.sqrt(n[:, 0] ** 2 + n[:, 2] ** 2)
        tan, bit = _orthonormal(n, torch.stack([n[:, 2], torch.zeros_like(u), -n[:, 0]], -1))
        hits = Hits(mask, t, p, tan, bit, n, torch.stack([u, v], -1), 2 * math.pi * r_xz,
                    torch.full_like(u, math.pi), (d * n).sum(-1).abs())
        return _masked(hits)


@dataclass
class Plane:
    """The square [-1, 1]^2 at y = 0 with uv repeated ``tiles`` times (module docstring)."""

    tiles: float = 2.0

    def bounds(self):
        return torch.zeros(3), math.sqrt(2.0)

    def intersect(self, rays: Rays) -> Hits:
        o, d = rays.origin, rays.dirs
        dy = torch.where(d[:, 1].abs() < 1e-9, torch.full_like(d[:, 1], 1e-9), d[:, 1])
        t = -o[..., 1] / dy
        p = o + t[:, None] * d
        mask = (t > rays.nearest()) & (p[:, 0].abs() <= 1) & (p[:, 2].abs() <= 1)
        side = torch.where(d[:, 1] < 0, 1.0, -1.0)[:, None]  # +1 seen from above
        n = torch.tensor([[0.0, 1.0, 0.0]]) * side
        tan = torch.tensor([[1.0, 0.0, 0.0]]).expand_as(p)
        bit = torch.tensor([[0.0, 0.0, -1.0]]) * side
        uv = torch.stack([(p[:, 0] + 1) / 2, (1 - p[:, 2]) / 2], -1) * self.tiles
        dens = torch.full_like(t, 2.0 / self.tiles)
        return _masked(Hits(mask, t, p, tan, bit.expand_as(p), n.expand_as(p).contiguous(), uv, dens, dens,
                            d[:, 1].abs()))


def _masked(h: Hits) -> Hits:
    """Zero every field where ``mask`` is False (so misses hold no NaNs)."""
    m = h.mask

    def z(x):
        return torch.where(m.view(-1, *([1] * (x.dim() - 1))), x, torch.zeros_like(x))

    return Hits(m, z(h.t), z(h.position), z(h.tangent), z(h.bitangent), z(h.normal), z(h.uv), z(h.dpdu),
                z(h.dpdv), z(h.cos))


@dataclass
class Mesh:
    """A triangle mesh: per render vertex ``positions``/``normals``/``tangents`` [V,3], ``uvs`` [V,2];
    ``triangles`` [T,3] int64; per triangle geometric normal, |dP/du|, |dP/dv| and uv handedness."""

    positions: torch.Tensor
    normals: torch.Tensor
    uvs: torch.Tensor
    triangles: torch.Tensor
    material_index: torch.Tensor | None = None
    """[T] int64 per triangle: which of a scene's materials it is drawn with (None: all material 0)."""
    tangents: torch.Tensor = field(init=False)

    def __post_init__(self):
        p = self.positions[self.triangles]
        uv = self.uvs[self.triangles]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        ok = det.abs() > 1e-12
        inv = torch.where(ok, 1.0 / torch.where(ok, det, torch.ones_like(det)), torch.zeros_like(det))[:, None]
        dpdu = (d2[:, 1:2] * e1 - d1[:, 1:2] * e2) * inv
        dpdv = (d1[:, 0:1] * e2 - d2[:, 0:1] * e1) * inv
        cross = torch.linalg.cross(e1, e2, dim=-1)
        area2 = cross.norm(dim=-1)
        self.geo_normal = cross / area2.clamp_min(1e-20)[:, None]
        big = torch.full_like(det, 1e12)  # a uv-degenerate triangle: treat as infinitely dense (lod 0)
        self.dpdu_len = torch.where(ok, dpdu.norm(dim=-1), big)
        self.dpdv_len = torch.where(ok, dpdv.norm(dim=-1), big)
        self.handed = torch.where((torch.linalg.cross(dpdu, dpdv, dim=-1) * cross).sum(-1) < 0, -1.0, 1.0)
        acc = torch.zeros_like(self.positions)
        w = F.normalize(dpdu, dim=-1) * area2[:, None]
        for k in range(3):
            acc.index_add_(0, self.triangles[:, k], w)
        self.tangents = acc

    def bounds(self):
        lo, hi = self.positions.min(0).values, self.positions.max(0).values
        c = (lo + hi) / 2
        return c, float((self.positions - c).norm(dim=-1).max())

    def intersect(self, rays: Rays) -> Hits:
        if rays.project is None:
            raise ValueError("meshes are rasterised: the rays must come from Camera.rays or "
                             "OrthographicCamera.rays (Rays.project)")
        res = math.isqrt(len(rays.dirs))
        if res * res != len(rays.dirs):
            raise ValueError(f"meshes are rasterised into a square image; got {len(rays.dirs)} rays")
        sx, sy, z = rays.project(self.positions)  # column, row, depth
        tri = self.triangles
        x, y = sx[tri], sy[tri]
        j0 = (x.min(1).values - 1e-3).floor().clamp(0, res).long()
        j1 = (x.max(1).values + 1e-3).floor().clamp(-1, res - 1).long()
        i0 = (y.min(1).values - 1e-3).floor().clamp(0, res).long()
        i1 = (y.max(1).values + 1e-3).floor().clamp(-1, res - 1).long()
        behind = z[tri] <= 1e-6  # [T, 3]: corners at or behind the eye's plane project nowhere
        straddle = behind.any(1) & ~behind.all(1)
        j0, i0 = torch.where(straddle, 0, j0), torch.where(straddle, 0, i0)  # the whole image
        j1, i1 = torch.where(straddle, res - 1, j1), torch.where(straddle, res - 1, i1)
        j1 = torch.where(behind.all(1), -1, j1)  # wholly behind: no pixel
        w, h = (j1 - j0 + 1).clamp_min(0), (i1 - i0 + 1).clamp_min(0)
        count = w * h
        live = torch.nonzero(count > 0)[:, 0]
        npix = res * res
        best_t = torch.full((npix,), math.inf)
        best_k = torch.full((npix,), -1, dtype=torch.long)
        csum = torch.cumsum(count[live], 0)
        start = 0
        while start < len(live):  # chunks of triangles with at most CANDIDATE_CHUNK candidate pixels
            base = int(csum[start - 1]) if start else 0
            stop = max(start + 1, int(torch.searchsorted(csum, base + CANDIDATE_CHUNK, right=True)))
            ks = live[start:stop]
            cnt = count[ks]
            k = torch.repeat_interleave(ks, cnt)
            off = torch.arange(int(cnt.sum())) - torch.repeat_interleave(torch.cumsum(cnt, 0) - cnt, cnt)
            pix = (i0[k] + off // w[k]) * res + j0[k] + off % w[k]
            t, _, _ = self._ray_triangle(rays.origins(pix), rays.dirs[pix], k)
            t = torch.where(t > rays.nearest(pix), t, math.inf)
            ct = torch.full((npix,), math.inf).scatter_reduce(0, pix, t, "amin")
            win = torch.isfinite(t) & (t == ct[pix])
            ck = torch.full((npix,), torch.iinfo(torch.long).max).scatter_reduce(0, pix[win], k[win], "amin")
            better = (ct < best_t) | ((ct == best_t) & (ck < best_k) & torch.isfinite(ct))
            best_t, best_k = torch.where(better, ct, best_t), torch.where(better, ck, best_k)
            start = stop
        return self._shade(rays, best_k)

    def _ray_triangle(self, origin, dirs, k):
        """Moller-Trumbore: (t, b1, b2) per (ray, triangle); t = inf where the ray misses."""
        p = self.positions[self.triangles[k]]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        pv = torch.linalg.cross(dirs, e2, dim=-1)
        det = (e1 * pv).sum(-1)
        inv = 1.0 / torch.where(det.abs() > 1e-20, det, torch.full_like(det, 1e-20))
        s = origin - p[:, 0]
        b1 = (s * pv).sum(-1) * inv
        q = torch.linalg.cross(s, e1, dim=-1)
        b2 = (dirs * q).sum(-1) * inv
        t = (e2 * q).sum(-1) * inv
        eps = 1e-6
        ok = (det.abs() > 1e-20) & (b1 >= -eps) & (b2 >= -eps) & (b1 + b2 <= 1 + eps)
        return torch.where(ok, t, torch.full_like(t, math.inf)), b1, b2

    def _shade(self, rays: Rays, best_k: torch.Tensor) -> Hits:
        hits = Hits.empty(len(best_k))
        idx = torch.nonzero(best_k >= 0)[:, 0]
        if len(idx) == 0:
            return hits
        k = best_k[idx]
        dirs, origin = rays.dirs[idx], rays.origins(idx)
        t, b1, b2 = self._ray_triangle(origin, dirs, k)
        bary = torch.stack([1 - b1 - b2, b1, b2], -1).clamp_min(0)
        bary = bary / bary.sum(-1, keepdim=True)
        tri = self.triangles[k]

        def interp(a):
            return (a[tri] * bary[..., None]).sum(1)

        n = F.normalize(interp(self.normals), dim=-1)
        tan, bit = _orthonormal(n, interp(self.tangents), self.handed[k])
        gn = self.geo_normal[k]
        hits.mask[idx] = True
        for name, val in (("t", t), ("position", origin + t[:, None] * dirs), ("tangent", tan),
                          ("bitangent", bit), ("normal", n), ("uv", interp(self.uvs)),
                          ("dpdu", self.dpdu_len[k]), ("dpdv", self.dpdv_len[k]),
                          ("material", self.material_index[k] if self.material_index is not None
                           else torch.zeros_like(k)),
                          ("cos", (dirs * gn).sum(-1).abs())):
            getattr(hits, name)[idx] = val
        return hits


def load_obj(path) -> Mesh:
    """A :class:`Mesh` from a Wavefront OBJ (v, vt, vn, polygonal f; fan-triangulated).

    Corners with the same (v, vt, vn) share a render vertex, so uv seams split
    vertices. Without vt, uv is 0 and the lod 0; without vn, normals are the
    area-weighted average of the adjacent faces. Raises InputError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such OBJ file; pass --geometry sphere|plane|teapot or an existing .obj")
    v, vt, vn, corners, faces = [], [], [], [], []
    try:
        for line in path.read_text(errors="replace").splitlines():
            tok = line.split()
            if not tok:
                continue
            if tok[0] == "v":
                v.append([float(a) for a in tok[1:4]])
            elif tok[0] == "vt":
                vt.append([float(a) for a in tok[1:3]])
            elif tok[0] == "vn":
                vn.append([float(a) for a in tok[1:4]])
            elif tok[0] == "f":
                ids = []
                for c in tok[1:]:
                    parts = (c.split("/") + ["", ""])[:3]
                    ids.append([int(a) if a else 0 for a in parts])
                first = len(corners)
                corners.extend(ids)
                faces.extend([first, first + i, first + i + 1] for i in range(1, len(ids) - 1))
    except (ValueError, IndexError) as exc:
        raise InputError(f"{path}: malformed OBJ ({exc})") from None
    if not v or not faces:
        raise InputError(f"{path}: the OBJ has no vertices or faces")
    c = np.asarray(corners, dtype=np.int64)
    for col, n in ((0, len(v)), (1, len(vt)), (2, len(vn))):  # 1-based, negative = from the end, 0 = absent
        c[:, col] = np.where(c[:, col] < 0, c[:, col] + n + 1, c[:, col])
        if ((c[:, col] < 0) | (c[:, col] > n)).any():
            raise InputError(f"{path}: a face refers to a missing vertex attribute")
    if (c[:, 0] == 0).any():
        raise InputError(f"{path}: a face corner has no vertex index")
    uniq, inverse = np.unique(c, axis=0, return_inverse=True)
    tris = torch.from_numpy(inverse.reshape(-1)[np.asarray(faces)])
    pos = torch.tensor(v, dtype=torch.float32)[torch.from_numpy(uniq[:, 0] - 1)]
    uv_tab = torch.tensor([[0.0, 0.0]] + vt, dtype=torch.float32)
    uvs = uv_tab[torch.from_numpy(uniq[:, 1])]
    if vn and (uniq[:, 2] > 0).all():
        normals = F.normalize(torch.tensor(vn, dtype=torch.float32)[torch.from_numpy(uniq[:, 2] - 1)], dim=-1)
    else:  # area-weighted face normals, accumulated per position index
        p = pos[tris]
        fn = torch.linalg.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], dim=-1)
        acc = torch.zeros(len(v), 3)
        pid = torch.from_numpy(uniq[:, 0] - 1)[tris]
        for k in range(3):
            acc.index_add_(0, pid[:, k], fn)
        normals = F.normalize(acc[torch.from_numpy(uniq[:, 0] - 1)], dim=-1)
    return Mesh(pos, normals, uvs, tris)
