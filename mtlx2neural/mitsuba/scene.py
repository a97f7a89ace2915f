"""The project's renderer scenes as Mitsuba 3 scenes: an :class:`~mtlx2neural.render.in_scene.InScene`
(meshes, a pinhole camera, distant lights and lat-long environments) in Mitsuba's terms, one BSDF per
material, with each material's emission and opacity.

World space is the project's (:mod:`mtlx2neural.render.geometry`): right-handed, **y up**, stage units;
Mitsuba's scene is built in the same space, so no transform is applied anywhere. Images are
[res, res, 3] float32 linear RGB radiance, row 0 at the top, column 0 at the left, as
:func:`mtlx2neural.render.renderer.render_scene` writes them.

- **Meshes** (:func:`split_mesh`, :func:`make_mesh`): one ``mi.Mesh`` per material index of
  :attr:`.render.geometry.Mesh.material_index` (None: all material 0), holding that material's triangles
  with their world positions, unit vertex normals (Mitsuba's shading normals) and texture coordinates
  **exactly as the USD ``st``**: Mitsuba stores a mesh's ``vertex_texcoords`` as given and interpolates
  them into ``si.uv`` (no flip; only its OBJ loader flips v, by default), so a plugin reads the USD uv
  unchanged (origin at the texture's bottom left, v up). Mitsuba's frame is its own (``si.sh_frame.s``
  along dp/du of the triangle, Gram-Schmidt against the shading normal), not the torch renderer's
  smoothed per-vertex tangents.
- **Camera** (:func:`sensor_dict`): a ``perspective`` sensor at the :class:`.render.geometry.PinholeCamera`'s
  eye looking along its ``forward`` with its ``up`` (``look_at``), full field of view ``fov`` degrees
  on the square film (``fov_axis`` y), an ``hdrfilm`` of res x res RGB pixels with a ``box``
  reconstruction filter (each pixel averages its own samples, uniformly jittered over the pixel, as the
  torch renderer's do; Mitsuba's default Gaussian would blend neighbouring pixels, so the two renderers'
  images would differ by a blur) and an ``independent`` sampler. Mitsuba's image is not mirrored:
  world points right of and above the view direction land right of and above the centre, as in the torch
  renderer (``tests/mitsuba/test_mitsuba_scene.py`` compares the silhouettes).
- **Distant lights** (:class:`.render.lighting.DirectionalLight`, direction *towards* the light, RGB
  irradiance on a surface facing it): ``directional`` emitters with ``direction`` = -towards (Mitsuba's
  points the way the light travels) and the same ``irradiance``.
- **Environments** (:class:`.render.lighting.EnvironmentMap`, lat-long, nearest lookup, u = 0.5 +
  atan2(x, -z) / 2pi, v = acos(y) / pi): an ``envmap`` emitter (identity ``to_world``: Mitsuba's envmap is
  y up too) from a resampled bitmap (:func:`envmap_image`). Mitsuba looks its bitmap up bilinearly with
  u_m = atan2(x, -z) / 2pi (= u - 1/2) at column centres (j + 1/2) / W' (periodic) and rows at
  v = i / (H' - 1) (a row on each pole); the bitmap holds the project's radiance at those points, at
  :data:`ENV_UPSAMPLE` times the map's resolution, so Mitsuba's lookup in direction d is the project's
  radiance in d exactly wherever d lies more than one Mitsuba texel (1 / ENV_UPSAMPLE of a pixel) from
  a border of the project's pixels, and a blend of the two neighbours' values in that band.
- **Emission and opacity** (:func:`surface_terms`; radiance in linear RGB without a cosine, opacity a
  fraction or a cut-out's alpha-tested mask, :mod:`mtlx2neural.textures.surface_maps`): sampled from the
  material's ``emission(uv)`` / ``opacity(uv)`` (level of detail 0) at the texel centres of a grid over
  uv [0, 1]^2. The emission becomes an ``area`` emitter on the material's mesh, radiance = emission x
  opacity (MaterialX weights the emitted light by the opacity, as the torch renderer does; Mitsuba's
  emitter ignores the ``mask`` the path passes through, so the product is baked in); the opacity a ``mask``
  BSDF around the material's BSDF. A cut-out (a material with ``alpha_cutoff``, or whose samples are all 0
  or 1) is alpha-tested here, on a grid :data:`MASK_UPSAMPLE` times finer than the material's, and read
  with ``nearest`` filtering, so its edge stays within a fine texel of where the torch renderer's
  alpha test of the bilinear map puts it, instead of a bilinear band of partial cover; a blend is read
  bilinearly. A value equal everywhere is a plain float or RGB. Bitmap textures are ``raw`` (no colour
  conversion) and wrap; Mitsuba's bitmap puts v = 0 on its row 0 (image-space v down), so every grid
  (stored as the project does, row 0 at v = 1) is flipped upside down on the way in: Mitsuba's bilinear
  lookup at the USD uv is then :func:`mtlx2neural.imaging.grid_lookup.bilinear_periodic` of the grid.

Everything here takes the ``mitsuba`` module as its first argument (:func:`mtlx2neural.mitsuba.load_mitsuba`),
so importing this module needs no Mitsuba.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mtlx2neural.render.geometry import Mesh, PinholeCamera
from mtlx2neural.render.lighting import DirectionalLight, EnvironmentMap
from mtlx2neural.textures.surface_maps import ALPHA_CUTOFF, BINARY_TOLERANCE

ENV_UPSAMPLE = 8
"""Mitsuba envmap texels per project environment pixel, along each axis (at most :data:`MAX_ENV_WIDTH` wide)."""
MAX_ENV_WIDTH = 4096
"""Widest resampled environment bitmap, in texels."""
MASK_UPSAMPLE = 4
"""Alpha-tested texels per material texel, along each axis, of a cut-out's mask (at most :data:`MAX_GRID`)."""
SURFACE_GRID = (256, 256)
"""(rows, columns) over uv [0, 1]^2 sampling a material that has no texel grid of its own (a reference)."""
MAX_GRID = 2048
"""Largest side of an emission or opacity grid, in texels."""
UNIFORM_TOLERANCE = 1e-6
"""Samples within this of each other make a constant (a plain float or RGB, not a bitmap)."""


# ----------------------------------------------------------------------------- geometry


def split_mesh(mesh: Mesh) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """``[(material index, positions [V,3], normals [V,3], uvs [V,2], faces [T,3] uint32)]``: the triangles of
    each material index of ``mesh`` (None: all 0) with only the vertices they use, float32 world units."""
    tris = mesh.triangles.numpy()
    index = (mesh.material_index.numpy() if mesh.material_index is not None
             else np.zeros(len(tris), np.int64))
    pos, nrm, uv = (t.detach().numpy().astype(np.float32) for t in (mesh.positions, mesh.normals, mesh.uvs))
    out = []
    for m in np.unique(index).tolist():
        sub = tris[index == m]
        used, faces = np.unique(sub.reshape(-1), return_inverse=True)
        out.append((int(m), pos[used], nrm[used], uv[used], faces.reshape(-1, 3).astype(np.uint32)))
    return out


def make_mesh(mi, name: str, positions, normals, uvs, faces, bsdf, emitter=None):
    """An ``mi.Mesh`` of the given arrays (module docstring: world positions, unit shading normals, the USD
    uv as they are) with ``bsdf`` (a loaded BSDF or its dict) and, optionally, an ``area`` ``emitter``."""
    props = mi.Properties()
    props["bsdf"] = bsdf if not isinstance(bsdf, dict) else mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = emitter if not isinstance(emitter, dict) else mi.load_dict(emitter)
    mesh = mi.Mesh(name, len(positions), len(faces), props=props, has_vertex_normals=True,
                   has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(positions, np.float32).ravel())
    params["vertex_normals"] = mi.Float(np.ascontiguousarray(normals, np.float32).ravel())
    params["vertex_texcoords"] = mi.Float(np.ascontiguousarray(uvs, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
    params.update()
    return mesh


# ----------------------------------------------------------------------------- camera


def sensor_dict(mi, camera: PinholeCamera, res: int, spp: int, bounds=None) -> dict:
    """The ``perspective`` sensor of ``camera`` (module docstring), res x res ``hdrfilm`` (box filter), an
    ``independent`` sampler of ``spp`` samples per pixel. ``bounds`` (centre, radius of the geometry, world
    units) sets the clipping planes around it (default: Mitsuba's)."""
    d, _, up = camera.basis()
    eye = [float(v) for v in camera.position]
    target = [e - float(v) for e, v in zip(eye, d)]
    out = {"type": "perspective", "fov": float(camera.fov), "fov_axis": "y",
           "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=target, up=[float(v) for v in up]),
           "film": {"type": "hdrfilm", "width": int(res), "height": int(res), "pixel_format": "rgb",
                    "rfilter": {"type": "box"}},
           "sampler": {"type": "independent", "sample_count": int(spp)}}
    if bounds is not None:
        centre, radius = bounds
        far = 2.0 * (float(np.linalg.norm(np.asarray(eye) - np.asarray(centre, dtype=np.float64))) + float(radius)) + 1e-3
        out.update(near_clip=far * 1e-6, far_clip=far)
    return out


# ----------------------------------------------------------------------------- lights


def envmap_image(env: EnvironmentMap, upsample: int = ENV_UPSAMPLE) -> np.ndarray:
    """[H', W', 3] float32: ``env``'s radiance at the points Mitsuba's ``envmap`` interpolates between
    (module docstring): W' = k W columns at u_m = (j + 1/2) / W', H' = k H + 1 rows at v = i / (H' - 1),
    k = ``upsample`` (fewer when W' would pass :data:`MAX_ENV_WIDTH`), each the project's pixel under
    (u = u_m + 1/2, v) (nearest, as :meth:`EnvironmentMap.radiance`)."""
    h, w = env.height, env.width
    k = max(1, min(int(upsample), MAX_ENV_WIDTH // max(w, 1)))
    wm, hm = k * w, k * h + 1
    u = ((np.arange(wm) + 0.5) / wm + 0.5) % 1.0
    v = np.arange(hm) / (hm - 1)
    col = np.clip(np.floor(u * w).astype(np.int64), 0, w - 1)
    row = np.clip(np.floor(v * h).astype(np.int64), 0, h - 1)
    img = env.image.numpy()
    return np.ascontiguousarray(img[row[:, None], col[None, :]], dtype=np.float32)


def emitter_dicts(mi, lights) -> dict:
    """``{"light_<i>": emitter dict}`` for a sequence of :class:`DirectionalLight` / :class:`EnvironmentMap`
    (module docstring); TypeError for any other light."""
    out = {}
    for i, li in enumerate(lights):
        if isinstance(li, DirectionalLight):
            towards = li.vector().tolist()
            out[f"light_{i}"] = {"type": "directional", "direction": [-float(c) for c in towards],
                                 "irradiance": {"type": "rgb", "value": [float(c) for c in li.rgb().tolist()]}}
        elif isinstance(li, EnvironmentMap):
            out[f"light_{i}"] = {"type": "envmap", "bitmap": mi.Bitmap(envmap_image(li))}
        else:
            raise TypeError(f"unsupported light {type(li).__name__}")
    return out


# ----------------------------------------------------------------------------- emission and opacity


@dataclass
class SurfaceTerms:
    """A material's emission and opacity as Mitsuba reads them (module docstring): each None (none /
    opaque), a constant, or a grid ([H, W, 3] radiance, [H, W] opacity; row 0 at v = 1, as the project
    stores maps). ``emission`` is already multiplied by the opacity; ``cutout``: the opacity was alpha-tested."""

    emission: np.ndarray | tuple | None = None
    opacity: np.ndarray | float | None = None
    cutout: bool = False

    @property
    def empty(self) -> bool:
        return self.emission is None and self.opacity is None


def grid_uv(shape: tuple[int, int]) -> torch.Tensor:
    """[H*W, 2] uv of the texel centres of an (H, W) grid over [0, 1]^2, row-major, row 0 at v = 1."""
    h, w = shape
    u = (torch.arange(w, dtype=torch.float32) + 0.5) / w
    v = 1.0 - (torch.arange(h, dtype=torch.float32) + 0.5) / h
    return torch.stack([u[None, :].expand(h, w), v[:, None].expand(h, w)], -1).reshape(-1, 2)


def material_grid(material, fallback: tuple[int, int] = SURFACE_GRID) -> tuple[int, int]:
    """(H, W) of the texel grid ``material``'s emission and opacity are sampled on: the level-0 shape of
    its own maps (a model's ``surface``), else ``fallback``."""
    maps = getattr(material, "surface", None)
    for levels in (getattr(maps, "emission_levels", None), getattr(maps, "opacity_levels", None)):
        if levels:
            return int(levels[0].shape[-2]), int(levels[0].shape[-1])
    return int(fallback[0]), int(fallback[1])


def _uniform(x: np.ndarray) -> bool:
    return float(np.ptp(x.reshape(-1, x.shape[-1]) if x.ndim > 2 else x.reshape(-1), axis=0).max()) <= UNIFORM_TOLERANCE


def surface_terms(material, shape: tuple[int, int], chunk: int = 1 << 16) -> SurfaceTerms:
    """:class:`SurfaceTerms` of any material with ``emission(uv)`` / ``opacity(uv)`` (the reference, a model
    with its ``surface``; neither: nothing), sampled at the texel centres of ``shape`` (H, W) over uv
    [0, 1]^2 at level of detail 0, :data:`MASK_UPSAMPLE` times finer for a cut-out (module docstring)."""
    emission_fn, opacity_fn = getattr(material, "emission", None), getattr(material, "opacity", None)
    probe = grid_uv((2, 2))
    with torch.no_grad():
        emits = emission_fn is not None and emission_fn(probe) is not None
        opaque = opacity_fn is None or opacity_fn(probe) is None
    if not emits and opaque:
        return SurfaceTerms()
    h, w = shape
    if not opaque:
        h, w = min(h * MASK_UPSAMPLE, MAX_GRID), min(w * MASK_UPSAMPLE, MAX_GRID)
    uv = grid_uv((h, w))

    def sample(fn, c):
        with torch.no_grad():
            rows = [fn(uv[i:i + chunk]).reshape(-1, c).float().cpu() for i in range(0, len(uv), chunk)]
        return torch.cat(rows).numpy().reshape(h, w, c)

    out = SurfaceTerms()
    alpha = None
    if not opaque:
        alpha = sample(opacity_fn, 1)[..., 0]
        cutoff = getattr(material, "alpha_cutoff", None)
        binary = bool(((alpha < BINARY_TOLERANCE) | (alpha > 1 - BINARY_TOLERANCE)).all())
        out.cutout = cutoff is not None or binary
        alpha = ((alpha >= (cutoff if cutoff is not None else ALPHA_CUTOFF)).astype(np.float32) if out.cutout
                 else np.clip(alpha, 0.0, 1.0).astype(np.float32))
        out.opacity = float(alpha.flat[0]) if _uniform(alpha) else alpha
    if emits:
        e = sample(emission_fn, 3) * (alpha[..., None] if alpha is not None else 1.0)
        out.emission = tuple(float(c) for c in e[0, 0]) if _uniform(e) else e.astype(np.float32)
    if not isinstance(out.opacity, np.ndarray) and out.opacity == 1.0:
        out.opacity = None  # covered everywhere: no mask
    return out


def _bitmap_texture(mi, grid: np.ndarray, nearest: bool) -> dict:
    """A ``bitmap`` texture of a project grid ([H, W] or [H, W, C], row 0 at v = 1), flipped so that
    Mitsuba's lookup at uv reads the project's texel there (module docstring)."""
    img = np.flipud(grid if grid.ndim == 3 else grid[..., None])
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)), "raw": True,
            "filter_type": "nearest" if nearest else "bilinear", "wrap_mode": "repeat"}


def emission_emitter(mi, terms: SurfaceTerms) -> dict | None:
    """The ``area`` emitter of ``terms.emission`` (radiance), or None when nothing is emitted."""
    e = terms.emission
    if e is None:
        return None
    if isinstance(e, np.ndarray):
        return {"type": "area", "radiance": _bitmap_texture(mi, e, nearest=terms.cutout)}
    return {"type": "area", "radiance": {"type": "rgb", "value": [float(c) for c in e]}}


def masked_bsdf(mi, bsdf: dict, terms: SurfaceTerms) -> dict:
    """``bsdf`` wrapped in a ``mask`` of ``terms.opacity`` (nearest lookup for a cut-out), or ``bsdf`` itself
    when opaque."""
    o = terms.opacity
    if o is None:
        return bsdf
    opacity = _bitmap_texture(mi, o, nearest=terms.cutout) if isinstance(o, np.ndarray) else float(o)
    return {"type": "mask", "opacity": opacity, "bsdf": bsdf}


# ----------------------------------------------------------------------------- the scene


@dataclass
class Binding:
    """How one material index of a scene is drawn: ``bsdf`` (a Mitsuba BSDF dict: a plugin, ``diffuse``...)
    and ``surface`` (its emission and opacity, :func:`surface_terms`; None: none, opaque)."""

    bsdf: dict
    surface: SurfaceTerms | None = None


def scene_dict(mi, scene, bindings: list[Binding], res: int, spp: int, max_depth: int = 3,
               hide_emitters: bool = False) -> dict:
    """The Mitsuba scene dict of an :class:`~mtlx2neural.render.in_scene.InScene` (``geometry`` a
    :class:`Mesh`, ``camera`` a :class:`PinholeCamera`, ``lights``): one mesh per material index ``i``
    drawn with ``bindings[i]``, the ``path`` integrator (``max_depth``: Mitsuba's path length, 1 the
    emitters seen directly, 2 direct lighting, 3 one bounce more; ``hide_emitters``: a black background
    instead of the environment)."""
    out = {"type": "scene",
           "integrator": {"type": "path", "max_depth": int(max_depth), "hide_emitters": bool(hide_emitters)},
           "sensor": sensor_dict(mi, scene.camera, res, spp, scene.geometry.bounds())}
    for m, pos, nrm, uv, faces in split_mesh(scene.geometry):
        if m >= len(bindings):
            raise ValueError(f"the mesh draws material index {m}; only {len(bindings)} bindings are given")
        b = bindings[m]
        terms = b.surface or SurfaceTerms()
        out[f"mesh_{m}"] = make_mesh(mi, f"mesh_{m}", pos, nrm, uv, faces, masked_bsdf(mi, b.bsdf, terms),
                                     emission_emitter(mi, terms))
    out.update(emitter_dicts(mi, scene.lights))
    return out


def render(mi, scene, seed: int = 0, spp: int | None = None) -> np.ndarray:
    """[res, res, 3] float32 linear RGB of a Mitsuba scene (a loaded ``mi.Scene`` or its dict), row 0 at
    the top; ``seed`` the sampler's, ``spp`` the sensor's unless given.

    Rendered in Dr.Jit's wavefront mode (symbolic loops and calls off, for this call only): the
    ``mtlx_reference`` plugin hands every bounce's points to torch, which a symbolic (recorded) loop
    cannot do; the other BSDFs render the same either way."""
    # Local: Dr.Jit comes with Mitsuba, an optional dependency.
    import drjit as dr

    if isinstance(scene, dict):
        scene = mi.load_dict(scene)
    with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False), dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False):
        img = mi.render(scene, seed=int(seed), spp=int(spp) if spp else 0)
    out = np.asarray(img, dtype=np.float32)
    return np.ascontiguousarray(out[..., :3])


def pixel_ids(mi, scene, res: int) -> np.ndarray:
    """[res, res] int: the material index ``i`` of the mesh (``mesh_<i>``) that the ray through each pixel's
    centre first hits, -1 where it hits none (a cut-out's hole counts as a hit): which pixels show which
    material."""
    if isinstance(scene, dict):
        scene = mi.load_dict(scene)
    sensor = scene.sensors()[0]
    rows, cols = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    pos = mi.Point2f(((cols.ravel() + 0.5) / res).astype(np.float32), ((rows.ravel() + 0.5) / res).astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    hit = np.asarray(si.is_valid(), dtype=bool)
    out = np.full(res * res, -1, np.int64)
    for shape in scene.shapes():
        name = shape.id()
        if name.startswith("mesh_"):
            out[np.asarray(si.shape == mi.ShapePtr(shape), dtype=bool) & hit] = int(name.split("_")[-1])
    return out.reshape(res, res)
