"""In-scene fidelity: a material rendered on its stage's own bound meshes, seen by the stage's camera
and lit by the stage's lights, reference against model.

The analytic views (:func:`.renderer.compare`: a unit sphere, three azimuth/elevation views, one
directional light each) measure a material everywhere the same way; a material is seen in its
scene, though, at the distances, angles and lighting its stage gives it. :func:`stage_in_scene`
builds that scene from :func:`mtlx2neural.scene.stage_render.read_stage_view`:

- geometry: the material's bound meshes (and tessellated ``Sphere`` gprims) as one
  :class:`.geometry.Mesh` in world space (y up; stage units). Corners with equal position, uv and
  normal share a vertex (smooth tangents). Above :data:`MAX_TRIANGLES` a seeded random subset of
  triangles is kept, the same for both renders (the holes are black in both), so the render time
  stays bounded whatever the asset;
- camera: the stage's first perspective camera (:class:`.geometry.PinholeCamera`, the centre
  square of its frame), else, or when it sees less than :data:`MIN_COVERAGE` of the image's
  pixels on those meshes, :func:`.geometry.framing_camera` of their bounding sphere
  (azimuth 30, elevation 25 degrees, 30 degree field of view);
- lights: each ``DistantLight`` as a :class:`.lighting.DirectionalLight` (irradiance
  ``intensity * color * 2^exposure``), each ``DomeLight`` as an :class:`.lighting.EnvironmentMap`
  (its lat-long texture turned from the OpenEXR orientation, centre +z, into this renderer's,
  centre -z, times that factor; uniform radiance without a texture); with none of these, the
  procedural sky (:meth:`.lighting.EnvironmentMap.sky`).

:func:`compare_in_scene` renders the reference and each model with the same seed (common random
numbers; under environment lights both take the directions of an equal mixture of the reference's and that model's
samplers, as the summary's sky view does, so the reference is rendered once per model) at :data:`RES` pixels and
:data:`SPP` samples, and reports HDR FLIP **over the pixels that show the meshes** (``flip``;
the black background would otherwise dilute it by the empty share of the frame, which the stage's
framing decides) and over the whole image (``flip_image``, the convention of the analytic views'
``flip_mean``, whose sphere covers about 65 % of each view).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.geometry import Mesh, PinholeCamera, framing_camera
from mtlx2neural.render.lighting import DirectionalLight, EnvironmentMap
from mtlx2neural.render.mixture_sampler import MixtureSampler
from mtlx2neural.render.renderer import image_errors, render_scene

RES = 96
"""Pixels across the square in-scene image."""
SPP = 16
"""Jittered samples per pixel of the in-scene render."""
MAX_TRIANGLES = 200_000
"""Triangles rasterised at most (a seeded random subset above it)."""
MIN_COVERAGE = 0.01
"""Share of the image the stage camera must show of the meshes, else the framing camera is used."""
FRAMING = {"azimuth": 30.0, "elevation": 25.0, "fov": 30.0}


@dataclass
class InScene:
    """A built in-scene setup: what :func:`.renderer.render_scene` takes, and ``record``, how it was
    viewed and lit (JSON-ready: the summary's ``in_scene``)."""

    geometry: Mesh
    camera: PinholeCamera
    lights: list
    record: dict


def mesh_from_triangles(positions, uvs, normals) -> Mesh:
    """A :class:`.geometry.Mesh` from per-corner arrays ([T, 3, 3], [T, 3, 2], [T, 3, 3]); corners
    with equal position, uv and normal become one vertex."""
    table = np.concatenate([positions, uvs, normals], -1).reshape(-1, 8)
    uniq, inverse = np.unique(table, axis=0, return_inverse=True)
    t = torch.from_numpy(uniq.astype(np.float32))
    return Mesh(t[:, :3].contiguous(), F.normalize(t[:, 5:8], dim=-1), t[:, 3:5].contiguous(),
                torch.from_numpy(inverse.reshape(-1, 3).astype(np.int64)))


def _lights(view) -> tuple[list, list[str]]:
    lights, described = [], []
    for li in view.lights:
        rgb = np.asarray(li.rgb, dtype=np.float32)
        if li.kind == "distant":
            lights.append(DirectionalLight(tuple(li.direction), tuple(rgb.tolist())))
            described.append(f"{li.path}: distant, towards {np.round(li.direction, 3).tolist()}, "
                             f"irradiance {np.round(rgb, 4).tolist()}")
        elif li.texture:
            env = EnvironmentMap.from_file(li.texture)
            img = env.image.numpy()
            img = np.roll(img, -(img.shape[1] // 2), axis=1) * rgb  # OpenEXR lat-long: centre +z
            lights.append(EnvironmentMap(img, name=li.texture))
            described.append(f"{li.path}: dome, texture {li.texture} x {np.round(rgb, 4).tolist()}")
        else:
            lights.append(EnvironmentMap(np.ones((8, 16, 3), np.float32) * rgb, name=li.path))
            described.append(f"{li.path}: dome, uniform radiance {np.round(rgb, 4).tolist()}")
    if not lights:
        lights.append(EnvironmentMap.sky())
        described.append("the procedural sky (the stage has no distant or dome light)")
    return lights, described


def setup_in_scene(view, res: int = RES, max_triangles: int = MAX_TRIANGLES, seed: int = 0) -> InScene | str:
    """The :class:`InScene` of a :class:`~mtlx2neural.scene.stage_render.StageView`, or why there is
    none (no bound triangles)."""
    n = len(view.positions)
    if n == 0:
        return "no bound mesh or sphere could be read: " + ("; ".join(view.notes) or "none is bound")
    notes = list(view.notes)
    keep = np.arange(n)
    if n > max_triangles:
        keep = np.sort(np.random.default_rng(seed).choice(n, max_triangles, replace=False))
        notes.append(f"{n} triangles: a seeded random {max_triangles} of them are rendered")
    mesh = mesh_from_triangles(view.positions[keep], view.uvs[keep], view.normals[keep])
    centre, radius = mesh.bounds()
    framing = framing_camera(centre, radius, **FRAMING)
    camera, how = framing, (f"framing camera of the bound meshes' bounding sphere (azimuth {FRAMING['azimuth']}, "
                            f"elevation {FRAMING['elevation']}, fov {FRAMING['fov']} degrees)")
    if view.camera is not None:
        c = view.camera
        stage_cam = PinholeCamera(tuple(c.position.tolist()), tuple(c.forward.tolist()), tuple(c.up.tolist()), c.fov)
        seen = coverage(mesh, stage_cam, res)
        if seen >= MIN_COVERAGE:
            camera, how = stage_cam, f"{c.path} (fov {c.fov:.2f} degrees, the centre square of its frame)"
        else:
            notes.append(f"{c.path} sees {seen:.1%} of its image on the bound meshes (< {MIN_COVERAGE:.0%}): "
                         f"the framing camera is used")
    lights, described = _lights(view)
    record = {"camera": how, "eye": [round(float(v), 4) for v in camera.position],
              "lights": described, "prims": list(view.prims), "triangles": int(len(keep)),
              "up_axis": view.up_axis, "notes": notes}
    return InScene(mesh, camera, lights, record)


def stage_in_scene(stage_file, prims, res: int = RES) -> InScene | str:
    """:func:`setup_in_scene` of the bound ``prims`` of the USD file ``stage_file``, or why not."""
    # Local: reading a stage loads pxr, which a .mtlx conversion never needs.
    from mtlx2neural.scene.stage_render import read_stage_view

    return setup_in_scene(read_stage_view(stage_file, prims), res)


def coverage(mesh: Mesh, camera, res: int) -> float:
    """Share of the image's pixel centres (one jittered ray each, seed 0) that hit ``mesh``."""
    centre, radius = mesh.bounds()
    return float(mesh.intersect(camera.rays(res, centre, radius, torch.Generator().manual_seed(0))).mask
                 .float().mean())


def compare_in_scene(reference, models: dict, texels: tuple[int, int], scene: InScene, res: int = RES,
                     spp: int = SPP, seed: int = 0) -> dict:
    """``{label: {"reference": image, label: image, "flip", "flip_image", "flip_map", "mae", "relmse",
    "coverage", "res", "spp", "seconds"}}`` for each model of ``models`` against one reference render of ``scene``
    (module docstring: ``flip`` over the pixels showing the meshes, ``flip_image`` over all; ``mae``,
    ``relmse`` over all, as :func:`.renderer.image_errors`; ``coverage`` the share of pixels that show
    the meshes; ``seconds`` the wall time of the reference render and this model's, with the errors).
    When the reference render is black everywhere (nothing lit, or back faces only) the FLIP figures
    are NaN: there is nothing to measure."""
    env = any(isinstance(li, EnvironmentMap) for li in scene.lights)

    def draw(material, sampler=None):
        return render_scene(material, scene.geometry, scene.camera, scene.lights, res, spp, texels, seed,
                            sampler=sampler)

    t0 = time.time()
    shared = None if env else draw(reference)  # under directional lights alone no direction is sampled
    ref_seconds = time.time() - t0
    mask = coverage(scene.geometry, scene.camera, res)  # the share; the pixels, from the renders
    out = {}
    for label, model in models.items():
        t1 = time.time()
        # Under an environment both renders take one mixture's directions (common random numbers): the
        # reference's sampler alone finds a near mirror's peak but reaches the model's wider lobe only with
        # rare, huge weights, and the model's figure was that noise (the sample near mirror: 0.42).
        sampler = MixtureSampler(reference, model) if env else None
        ref = shared if shared is not None else draw(reference, sampler)
        test = draw(model, sampler)
        if float(ref.max()) > 0:
            errors = image_errors(ref, test)
            raw, _, _ = hdr_flip(ref, test, apply_magma=False)
            shown = (ref.sum(-1) > 0) | (test.sum(-1) > 0)
            flip = float(raw[..., 0][shown].mean())
        else:  # nothing lit in the reference: nothing to measure
            errors = {"flip": math.nan, "flip_map": np.zeros_like(ref), "mae": float(np.abs(test - ref).mean()),
                      "relmse": math.nan}
            flip = math.nan
        out[label] = {"reference": ref, label: test, **errors, "flip_image": errors["flip"], "flip": flip,
                      "coverage": round(mask, 4), "res": res, "spp": spp,
                      "seconds": round(ref_seconds + time.time() - t1, 2)}  # the model's reference render included
    return out
