"""What a USD stage gives for rendering one material in place: its bound meshes, the camera, the lights.

The conversion measures a material's fidelity on the stage's own geometry
(:mod:`mtlx2neural.render.in_scene`); this module reads what that render needs and nothing
else, as plain numpy arrays (the renderer's types live a layer above).

Frames and units:

- **World** is the stage's world space at the default time, in stage units (``metersPerUnit``
  not applied), turned so that the stage's up axis is **+y**, the renderer's convention
  (:mod:`mtlx2neural.render.geometry`): a Z-up stage's (x, y, z) reads (x, z, -y), a rotation,
  so handedness and lengths are kept.
- **Triangles** (:class:`StageView`): every bound ``Mesh`` (or ``GeomSubset``) read by
  :mod:`.uv_raster`'s mesh reader (fan-triangulated polygons, the authored normals else the
  triangle's, ``st`` else the first texCoord2f[] primvar; without one uv is 0, so a textured
  material shows its texel at (0, 0)), and every bound ``Sphere`` gprim tessellated with the
  renderer's spherical layout (u = 0.5 + atan2(x, z) / 2pi around its y axis, v = acos(-y) / pi,
  :data:`SPHERE_SEGMENTS`). Per corner: world positions, uvs, unit world normals. Other gprims
  (Cube, Cylinder...) are left out with a note naming them.
- **Camera** (:class:`StageCamera`): the first ``Camera`` prim in stage order that is
  perspective. Its eye, view direction (its local -z) and image up (its +y) are world vectors;
  the square image the renderer draws is the centre square of its frame, so the field of view is
  that of the smaller aperture: ``2 atan(aperture / (2 focalLength))`` (both in the same tenths
  of a unit, so the ratio has no unit). Clipping planes, lens distortion and depth of field are
  ignored; an orthographic camera is skipped with a note.
- **Lights** (:class:`StageLight`, visible ones only):
  ``DistantLight``: ``direction`` is the unit world vector *towards* the light (the light shines
  along its local -z), ``rgb`` = ``intensity * color * 2^exposure``, the irradiance it delivers
  to a surface facing it (its ``angle`` is ignored: a point-like sun);
  ``DomeLight``: ``rgb`` = the same product, the radiance of an untextured dome, else the factor
  on its ``texture:file`` (resolved absolute path; a lat-long image in the OpenEXR orientation,
  pole along the stage's up axis; the dome's own rotation is ignored, with a note when it has one).
  Every other light type (Sphere, Rect, Disk, Cylinder, Geometry, Portal, plugin lights) is left
  out with a note naming it. ``colorTemperature`` is ignored (noted when enabled).

Only the material's own meshes are read: other geometry neither occludes nor shadows them in
the in-scene render.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtlx2neural.scene.mesh_reading import mesh_triangles

SPHERE_SEGMENTS = (48, 24)
"""(around, pole to pole) quads of a tessellated ``Sphere`` gprim."""

Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Row-vector rotation taking a Z-up stage's world to +y up: [x, y, z] @ R = [x, z, -y]."""


@dataclass
class StageCamera:
    """A stage's perspective camera (module docstring): world ``position``, unit ``forward`` (view
    direction) and ``up``; ``fov`` degrees across the square image; lens values as authored."""

    path: str
    position: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    fov: float
    focal_length: float
    aperture: tuple[float, float]
    """(horizontal, vertical), as authored (tenths of a stage unit, millimetres by convention)."""


@dataclass
class StageLight:
    """A light the in-scene render uses (module docstring for each kind's values)."""

    path: str
    kind: str
    """``distant`` or ``dome``."""
    rgb: tuple[float, float, float]
    """``intensity * color * 2^exposure``: irradiance (distant) or radiance factor (dome)."""
    direction: tuple[float, float, float] | None = None
    """Distant: unit world vector towards the light."""
    texture: str | None = None
    """Dome: the lat-long image's absolute path, or None (a uniform dome)."""


@dataclass
class StageView:
    """The bound geometry, camera and lights of one material on a stage (module docstring)."""

    positions: np.ndarray
    """[T, 3, 3] float64 world positions of each triangle's corners."""
    uvs: np.ndarray
    """[T, 3, 2] float64 texture coordinates."""
    normals: np.ndarray
    """[T, 3, 3] float64 unit world normals."""
    prims: list[str]
    """The bound prims read (the others are named in ``notes``)."""
    camera: StageCamera | None
    lights: list[StageLight]
    up_axis: str
    meters_per_unit: float
    notes: list[str] = field(default_factory=list)


def read_stage_view(stage, prims) -> StageView:
    """The :class:`StageView` of the bound ``prims`` (paths) of ``stage`` (a ``Usd.Stage`` or a file
    path, opened with :func:`.usd_stage.open_stage`)."""
    # Local: pxr's plugins load only when a stage is read (a .mtlx conversion never needs them).
    from pxr import Usd, UsdGeom

    # Local: the stage opener is a pxr-bound module of this layer.
    from mtlx2neural.scene.usd_stage import open_stage

    if not isinstance(stage, Usd.Stage):
        stage = open_stage(str(stage))
    up_axis = str(UsdGeom.GetStageUpAxis(stage))
    turn = Z_UP_TO_Y_UP if up_axis == "Z" else np.eye(3)
    notes, read, pos, uvs, nrm = [], [], [], [], []
    for path in dict.fromkeys(str(p) for p in prims):
        prim = stage.GetPrimAtPath(path)
        if prim and prim.IsA(UsdGeom.Sphere):
            found = _sphere_triangles(prim)
        else:
            found = mesh_triangles(stage, path, (), need_uv=False)
            if not isinstance(found, str):
                tuv, corners = found
                found = (corners["position:world"], tuv, corners["normal:world"])
        if isinstance(found, str):
            notes.append(f"{path}: {found}: left out of the in-scene render")
            continue
        read.append(path)
        pos.append(found[0] @ turn)
        uvs.append(found[1])
        nrm.append(found[2] @ turn)
    camera, cam_notes = _first_camera(stage, turn)
    lights, light_notes = _lights(stage, turn)
    cat = (lambda parts, c: np.concatenate(parts) if parts else np.zeros((0, 3, c)))
    return StageView(cat(pos, 3), cat(uvs, 2), cat(nrm, 3), read, camera, lights, up_axis,
                     float(UsdGeom.GetStageMetersPerUnit(stage)), notes + cam_notes + light_notes)


def _world(prim) -> np.ndarray:
    """[4, 4] local-to-world matrix at the default time (row-vector convention)."""
    # Local: pxr loads only when a stage is read.
    from pxr import Usd, UsdGeom

    return np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))


def _sphere_triangles(prim):
    """(positions, uvs, normals) [T, 3, C] world of a ``Sphere`` gprim (module docstring)."""
    # Local: pxr loads only when a stage is read.
    from pxr import UsdGeom

    r = float(UsdGeom.Sphere(prim).GetRadiusAttr().Get() or 1.0)
    nu, nv = SPHERE_SEGMENTS
    u, v = np.meshgrid(np.arange(nu + 1) / nu, np.arange(nv + 1) / nv)  # [nv+1, nu+1]
    phi, theta = (u - 0.5) * 2 * math.pi, v * math.pi
    n = np.stack([np.sin(theta) * np.sin(phi), -np.cos(theta), np.sin(theta) * np.cos(phi)], -1)
    uv = np.stack([u, v], -1)
    k = np.arange((nv + 1) * (nu + 1)).reshape(nv + 1, nu + 1)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, 1:].ravel(), k[1:, :-1].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])  # outward (right-handed)
    n, uv = n.reshape(-1, 3), uv.reshape(-1, 2)
    m = _world(prim)
    p = (np.hstack([n * r, np.ones((len(n), 1))]) @ m)[:, :3]
    wn = n @ np.linalg.inv(m[:3, :3]).T
    wn /= np.maximum(np.linalg.norm(wn, axis=-1, keepdims=True), 1e-30)
    return p[tris], uv[tris], wn[tris]


def _first_camera(stage, turn):
    """(the first perspective :class:`StageCamera` in stage order, or None; notes)."""
    # Local: pxr loads only when a stage is read.
    from pxr import Gf, Usd, UsdGeom

    notes = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Camera):
            continue
        cam = UsdGeom.Camera(prim).GetCamera(Usd.TimeCode.Default())
        if cam.projection != Gf.Camera.Perspective:
            notes.append(f"{prim.GetPath()}: orthographic camera: not used for the in-scene render")
            continue
        m = _world(prim)
        focal, ha, va = float(cam.focalLength), float(cam.horizontalAperture), float(cam.verticalAperture)
        if focal <= 0 or min(ha, va) <= 0:
            notes.append(f"{prim.GetPath()}: camera with focal length {focal} and aperture {ha} x {va}: not used")
            continue
        fov = math.degrees(2 * math.atan(min(ha, va) / (2 * focal)))
        unit = (lambda v: v / max(float(np.linalg.norm(v)), 1e-30))
        return StageCamera(str(prim.GetPath()), (m[3, :3] / m[3, 3]) @ turn, unit(-m[2, :3] @ turn),
                           unit(m[1, :3] @ turn), fov, focal, (ha, va)), notes
    return None, notes


def _lights(stage, turn):
    """(the visible distant and dome lights, notes naming the others)."""
    # Local: pxr loads only when a stage is read (module docstring of read_stage_view).
    from pxr import UsdGeom, UsdLux

    lights, notes = [], []
    for prim in stage.Traverse():
        if not prim.HasAPI(UsdLux.LightAPI):
            continue
        path = str(prim.GetPath())
        if prim.IsA(UsdGeom.Imageable) and UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.invisible:
            continue
        api = UsdLux.LightAPI(prim)
        get = (lambda attr, default: default if attr.Get() is None else attr.Get())
        scale = float(get(api.GetIntensityAttr(), 1.0)) * 2.0 ** float(get(api.GetExposureAttr(), 0.0))
        rgb = tuple(float(c) * scale for c in get(api.GetColorAttr(), (1.0, 1.0, 1.0)))
        if get(api.GetEnableColorTemperatureAttr(), False):
            notes.append(f"{path}: colorTemperature is ignored by the in-scene render")
        m = _world(prim)
        if prim.IsA(UsdLux.DistantLight):
            z = m[2, :3] @ turn
            lights.append(StageLight(path, "distant", rgb, tuple(z / max(float(np.linalg.norm(z)), 1e-30))))
        elif prim.IsA(UsdLux.DomeLight) or prim.GetTypeName() == "DomeLight_1":
            asset = prim.GetAttribute("inputs:texture:file").Get()
            texture = (asset.resolvedPath or asset.path) if asset is not None and asset.path else None
            if not np.allclose(m[:3, :3] / np.linalg.norm(m[:3, :3], axis=1, keepdims=True), np.eye(3), atol=1e-6):
                notes.append(f"{path}: the dome's rotation is ignored by the in-scene render")
            lights.append(StageLight(path, "dome", rgb, texture=texture or None))
        else:
            notes.append(f"{path}: {prim.GetTypeName() or 'light'}: not supported by the in-scene render "
                         f"(distant and dome lights only): ignored")
    return lights, notes
