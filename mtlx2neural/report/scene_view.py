"""The scene view of ``mtlx2neural report LAYER``: the whole converted stage in one image, three times,
and what the conversion cost and saved, material by material.

:func:`scene_view` gathers, for a layer whose input is a USD stage, every material the layer records
(converted ones from ``customLayerData["mtlx2neural"]["materials"]``, skipped ones from its
``skippedMaterials``) and renders their bound meshes together (one :class:`.render.geometry.Mesh` whose
``material_index`` picks each triangle's material) three times with :func:`.render.renderer.render_scene`:

- ``reference``: every material's MaterialX reference (:func:`mtlx2neural.load_reference` on the input,
  under the conversion's texture rules and ``--frame``/``--fps``);
- ``neural``: the exported neural models (:func:`mtlx2neural.load_neural`: FP16 latents and weights, with
  their emission and opacity maps), flagged ones included (the report shows what the quality gate judged);
- ``preview``: the UsdPreviewSurface fallback, the analytic Lambert + GGX baseline the conversion fitted
  (``<material folder>/analytic_baseline.pt``, shown with its ``surface_maps.pt``); the reference where the
  input's own UsdPreviewSurface is the fallback (the record's ``preview.own``).

A material the layer skipped, or whose neural model (or record) cannot be read, is drawn with its reference
in all three images (with missing textures at their declared defaults for a skipped one), or, when not even
its reference loads (an unsupported node), as a grey Lambert stand-in (albedo 0.18); the table says which.

**Rendering.** Camera and lights as the conversion's in-scene measure (:func:`.render.in_scene.setup_in_scene`:
the stage's first perspective camera, else the framing camera of the drawn meshes; its distant and dome
lights, else the procedural sky), ``res`` x ``res`` pixels (default :data:`RES`), ``spp`` jittered samples
(default :data:`SPP`), one ``seed`` for all three renders (common random numbers; under environment light
every render also samples the references' lobes). Above :data:`.render.in_scene.MAX_TRIANGLES` triangles a
seeded random subset is drawn. Images are linear RGB radiance (float32); the PNGs are sRGB at exposure 1.
Only the drawn materials' meshes are in the scene (no shadows, black background).

**HDR FLIP** (:func:`.render.flip.hdr_flip`) of the neural and the preview image against the reference:
the mean over the pixels that show a surface in either image (``flip``; the in-scene measure's
convention), and per material over the pixels whose centre ray (one jittered ray per pixel, seed 0) first
hits that material's triangles (``SceneEntry.flip``). NaN when the reference image is black everywhere.
The table's other FLIP figures are the conversion's record: ``flip_mean`` (three sphere views) and
``flip_in_scene`` (the material alone on its meshes).

**Memory, in bytes.** *Shipped*, per converted material, the files a renderer loads from
``<material folder>/neural/``: ``latents_*.exr`` / ``latents_*.dds``, ``weights.bin``, and ``emission.exr`` /
``opacity.exr`` when present. ``memory`` counts them as held for rendering: an EXR as the sum over its
stored MIP levels of width x height x channels x bytes per channel as stored (half: 2); a DDS as its block
data over every level (block compression stays compressed on the GPU; the headers are left out);
``weights.bin`` as its size. ``disk`` is the files' sizes. *Source*, per texture file a converted
material's MaterialX document reads (its ``filename`` inputs; a UDIM set counts every tile on disk):
width x height x channels x bytes per channel of the file's first image (8-bit PNG: 1, half EXR: 2,
float: 4), decoded, plus a third for a MIP chain (x 4/3, rounded down), whatever the file itself stores;
a file several materials read counts once in the total. Textures of skipped materials are left out
(they ship as before).

**Times, in seconds**, from the records: ``train_seconds`` (the optimisation) and ``seconds`` (the
material's whole conversion: compiling, training, measures, baseline fit); a material that shares another's
result (``shared_with``) counts 0.
"""

from __future__ import annotations

import dataclasses
import glob
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch

from mtlx2neural.baseline.analytic_model import BASELINE_FILE, load_analytic
from mtlx2neural.contract import estimate_albedo
from mtlx2neural.errors import InputError
from mtlx2neural.export.load import load_neural
from mtlx2neural.export.surface_files import EMISSION_FILE, OPACITY_FILE
from mtlx2neural.export.usd_writer import RECORD_KEY, register_schema
from mtlx2neural.formats.dds import read_dds
from mtlx2neural.imaging.resolve import on_disk
from mtlx2neural.material_record import MaterialRecord, read_record
from mtlx2neural.pipeline.layout import read_layer_record
from mtlx2neural.reference.loading import application_of, load_reference
from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.in_scene import MAX_TRIANGLES, setup_in_scene
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.renderer import render_scene
from mtlx2neural.render.udim_view import ClampToTiles, model_tiles
from mtlx2neural.scene.dependencies import USD_SUFFIXES
from mtlx2neural.textures.surface_maps import SURFACE_FILE, load_surface_maps

RES = 128
"""Pixels across the square scene image."""
SPP = 16
"""Jittered samples per pixel of each scene render."""
MIP_FACTOR = (4, 3)
"""A full MIP chain adds a third to a texture's level 0: bytes x 4 // 3."""
OWN_MODELS = "its neural model and its UsdPreviewSurface baseline"
"""``SceneEntry.drawn`` of a material drawn with its own three models."""
IMAGES = ("reference", "neural", "preview", "neural_flip", "preview_flip")
"""The scene view's images: three renders and two FLIP maps (magma, against the reference)."""


# ----------------------------------------------------------------------------- what a material contributes


@dataclass
class SceneEntry:
    """One material of the layer in the scene view (module docstring for units)."""

    prim: str
    status: str
    """``converted``, ``flagged`` (the quality gate's ``reasons`` in ``reason``), ``skipped`` (the layer's
    reason) or ``missing`` (the neural model or record cannot be read; why)."""
    reason: str = ""
    drawn: str = ""
    """How it is drawn, in words (its own models, its reference in all three, the grey stand-in)."""
    record: MaterialRecord | None = None
    folder: Path | None = None
    bound_prims: list[str] = field(default_factory=list)
    texels: tuple[int, int] = (1, 1)
    triangles: int = 0
    shipped: dict | None = None
    """:func:`shipped_bytes` of its export, for a converted (or flagged) material."""
    textures: dict[str, int] = field(default_factory=dict)
    """Source texture path -> bytes (:func:`texture_bytes`) of the textures its document reads."""
    flip: dict = field(default_factory=dict)
    """HDR FLIP over its own pixels in this scene render: ``{"neural", "preview"}`` (None: no pixel)."""
    models: dict = field(default_factory=dict, repr=False)
    """``{"reference", "neural", "preview"}``: what it is drawn with in each image."""

    def numbers(self) -> dict:
        r = self.record
        return {"material": self.prim, "status": self.status, "reason": self.reason, "drawn": self.drawn,
                "flip_scene_render": self.flip, "flip_mean": r.flip_mean if r else None,
                "preview_flip": r.preview_flip if r else None, "flip_in_scene": r.flip_in_scene if r else None,
                "preview_flip_in_scene": r.preview_flip_in_scene if r else None,
                "energy_min_ratio": (r.energy or {}).get("min_ratio") if r else None,
                "decoder": r.decoder if r else None, "train_seconds": r.train_seconds if r else None,
                "seconds": r.seconds if r else None, "surface": surface_kinds(r), "triangles": self.triangles,
                "shipped": self.shipped, "source_textures": self.textures}


def surface_kinds(record: MaterialRecord | None) -> dict:
    """``{"emission": none|constant|texture, "opacity": ..., "alpha_mode"}`` from the record's ``surface``."""
    s = (record.surface if record else None) or {}
    return {"emission": s.get("emission", "none"), "opacity": s.get("opacity", "none"),
            "alpha_mode": s.get("alpha_mode", "opaque")}


class GreyStandIn:
    """A grey Lambertian :class:`~mtlx2neural.contract.Material` (albedo :attr:`ALBEDO`) drawn for a material
    whose reference cannot be loaded: its meshes stay in the picture, the same in all three images."""

    ALBEDO = 0.18

    def eval(self, wi, wo, at=None):
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return torch.where(ok, wo[:, 2] * (self.ALBEDO / math.pi), 0.0)[:, None].expand(-1, 3).contiguous()

    def pdf(self, wi, wo, at=None):
        return torch.where((wi[:, 2] > 0) & (wo[:, 2] > 0), wo[:, 2] / math.pi, 0.0)

    def sample(self, wi, u, at=None):
        r, phi = u[:, 0].clamp(0, 1).sqrt(), 2 * math.pi * u[:, 1]
        wo = torch.stack([r * torch.cos(phi), r * torch.sin(phi), (1 - r * r).clamp_min(0).sqrt()], -1)
        pdf = self.pdf(wi, wo)
        weight = torch.where(pdf[:, None] > 0, torch.full_like(wo, self.ALBEDO), 0.0)
        return wo, weight, pdf

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0):
        return estimate_albedo(self, wi, at, samples, seed)

    def describe(self) -> dict:
        return {"model": "grey Lambert stand-in", "albedo": self.ALBEDO}


# ----------------------------------------------------------------------------- memory


def image_memory(path) -> int:
    """Bytes of an image as a renderer holds it (module docstring): a DDS's block data over its levels,
    any other image's texels over its stored MIP levels at the stored bytes per channel."""
    path = Path(path)
    if path.suffix.lower() == ".dds":
        return sum(len(level) for level in read_dds(path).levels)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: cannot be read as an image ({oiio.geterror()})")
    try:
        total, level = 0, 0
        while inp.seek_subimage(0, level):
            total += int(inp.spec(0, level).image_bytes(True))
            level += 1
        return total
    finally:
        inp.close()


def shipped_files(export: Path) -> dict[str, list[Path]]:
    """The files of an export folder a renderer loads: ``{"latent", "weights", "surface": [paths]}``."""
    export = Path(export)
    latents = sorted(export.glob("latents_*.exr")) + sorted(export.glob("latents_*.dds"))
    surface = [export / n for n in (EMISSION_FILE, OPACITY_FILE) if (export / n).is_file()]
    weights = [export / "weights.bin"] if (export / "weights.bin").is_file() else []
    return {"latent": latents, "weights": weights, "surface": surface}


def shipped_bytes(export: Path) -> dict:
    """``{"latent", "weights", "surface", "memory", "disk", "files"}`` of an export folder (module
    docstring: ``memory`` as held for rendering, ``disk`` the files' sizes; ``weights.bin`` counts its size)."""
    files = shipped_files(export)
    out = {"latent": sum(image_memory(p) for p in files["latent"]),
           "weights": sum(p.stat().st_size for p in files["weights"]),
           "surface": sum(image_memory(p) for p in files["surface"])}
    every = [p for ps in files.values() for p in ps]
    out["memory"] = out["latent"] + out["weights"] + out["surface"]
    out["disk"] = sum(p.stat().st_size for p in every)
    out["files"] = [p.name for p in every]
    return out


def texture_bytes(path) -> int | None:
    """Decoded bytes of a source texture with a MIP chain: width x height x channels x bytes per channel
    of its first image, x 4/3 rounded down (module docstring); None when it is not a readable image."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear it
        return None
    try:
        base = int(inp.spec().image_bytes(True))
    finally:
        inp.close()
    return base * MIP_FACTOR[0] // MIP_FACTOR[1]


def document_textures(document) -> list[Path]:
    """The texture files a MaterialX document's ``filename`` inputs read (a ``<UDIM>``/``<UVTILE>`` set:
    every tile on disk), absolute, existing, sorted."""
    found: set[Path] = set()
    for elem in document.traverseTree():
        if elem.getCategory() != "input" or elem.getAttribute("type") != "filename":
            continue
        value = elem.getResolvedValueString()
        if not value:
            continue
        if not os.path.isabs(value):
            base = elem.getActiveSourceUri()
            value = os.path.join(os.path.dirname(base), value) if base and not base.startswith("anon:") else value
        if "<UDIM>" in value or "<UVTILE>" in value:
            pattern = glob.escape(value).replace("<UDIM>", "[1-9][0-9][0-9][0-9]").replace("<UVTILE>", "u*_v*")
            found |= {Path(p).resolve() for p in glob.glob(pattern)}
        elif Path(on_disk(value)).is_file():
            found.add(Path(on_disk(value)).resolve())
    return sorted(p for p in found if p.suffix.lower() not in USD_SUFFIXES + (".mtlx",))


# ----------------------------------------------------------------------------- gathering the materials


def _reference(source: Path, names, allow_missing: bool, application=None):
    error = None
    for name in [n for n in names if n]:
        try:
            return load_reference(source, name, allow_missing_textures=allow_missing, application=application)
        except InputError as exc:  # the next name (a prim path, then the MaterialX name)
            error = exc
    raise error or InputError(f"{source}: no material named")


def _skipped_materials(layer: Path) -> dict[str, str]:
    """The layer record's ``skippedMaterials``: material -> reason."""
    # Local: pxr loads USD's plugins on import; the layer was opened through it already.
    from pxr import Sdf

    opened = Sdf.Layer.OpenAsAnonymous(str(layer))
    data = dict(opened.customLayerData).get(RECORD_KEY) if opened is not None else None
    return {str(k): str(v) for k, v in dict((data or {}).get("skippedMaterials") or {}).items()}


def _converted(layer: Path, source: Path, prim: str, entry: dict) -> SceneEntry:
    """A material the layer records as converted: its record, neural model and preview; ``missing`` when the
    record or the neural model cannot be read (then drawn with its reference)."""
    folder = (layer.parent / entry["folder"]).resolve() if entry.get("folder") else None
    try:
        if folder is None:
            raise InputError("the layer records no folder")
        record = read_record(folder)
        neural = load_neural(layer, prim)
    except (InputError, OSError) as exc:
        out = SceneEntry(prim, "missing", f"{type(exc).__name__}: {exc}", folder=folder)
        _as_reference(out, source, names=[prim], allow_missing=False)
        return out
    allow = bool((record.options or {}).get("allow_missing_textures", False))
    reference = _reference(source, [record.material, record.mtlx_material], allow, application_of(record.application))
    flagged = bool((record.quality or {}).get("flagged"))
    out = SceneEntry(prim, "flagged" if flagged else "converted",
                     "; ".join((record.quality or {}).get("reasons") or []), record=record, folder=folder,
                     bound_prims=list(record.bound_prims), texels=tuple(int(s) for s in record.resolution))
    preview, how = reference, "the reference in the preview image (no analytic_baseline.pt)"
    if (record.preview or {}).get("own"):  # the input's own UsdPreviewSurface is the fallback: the reference
        how = "its neural model; its own UsdPreviewSurface, the reference, in the preview image"
    elif (folder / BASELINE_FILE).is_file():
        try:
            preview = load_analytic(folder / BASELINE_FILE)
            maps = load_surface_maps(folder / SURFACE_FILE)  # the emission and opacity it is shown with
            preview.surface = maps if maps is not None else getattr(neural, "surface", None)
            how = OWN_MODELS
        except ValueError as exc:
            how = f"the reference in the preview image ({exc})"
    tiles = model_tiles(neural)
    if tiles:  # the meshes' own uv, kept inside the trained tiles (as the in-scene measure)
        neural = ClampToTiles(neural, tiles)
        preview = ClampToTiles(preview, model_tiles(preview)) if model_tiles(preview) else preview
    out.models = {"reference": reference, "neural": neural, "preview": preview}
    out.drawn = how
    out.shipped = shipped_bytes(folder / "neural")
    return out


def _as_reference(entry: SceneEntry, source: Path, names, allow_missing: bool) -> None:
    """Draw ``entry`` with its reference in all three images (or the grey stand-in, saying why)."""
    try:
        reference = _reference(source, names, allow_missing)
        entry.drawn = "its reference in all three images" + (
            " (missing textures at their declared defaults)" if allow_missing else "")
    except InputError as exc:
        reference = GreyStandIn()
        entry.drawn = f"a grey stand-in in all three images (its reference cannot be loaded: {exc})"
    entry.models = dict.fromkeys(("reference", "neural", "preview"), reference)


def gather(layer: Path) -> tuple[Path, list[SceneEntry]] | str:
    """(the input stage, one :class:`SceneEntry` per material of the layer), or why there is no scene."""
    layer = Path(layer).resolve()
    register_schema()  # before USD's schema registry is first used
    record = read_layer_record(layer)
    if record is None or record.source is None:
        return "the layer does not record its input, so there is no scene to draw"
    source = record.source
    if source.suffix.lower() not in USD_SUFFIXES:
        return f"the input {source.name} is not a USD stage (a MaterialX document or a measured table): there is no scene to draw"
    if not source.is_file():
        return f"the input {source} is missing, so there is no scene to draw"
    entries = [_converted(layer, source, e.get("prim") or name, e) for name, e in record.materials.items()]
    for prim, why in _skipped_materials(layer).items():
        entry = SceneEntry(prim, "skipped", why)
        _as_reference(entry, source, [prim], allow_missing=True)
        entries.append(entry)
    _bind_and_textures(source, entries)
    return source, entries


def _bind_and_textures(source: Path, entries: list[SceneEntry]) -> None:
    """Bound prims of the entries that have no record (from the stage's bindings) and every entry's source
    textures (from the input's MaterialX documents)."""
    # Local: the scene's USD modules import pxr and MaterialX, needed only for a stage's scene view.
    from mtlx2neural.scene import load_asset
    from mtlx2neural.scene.binding import collect_bindings

    # Local: as above (pxr).
    from mtlx2neural.scene.usd_stage import open_stage

    if any(not e.bound_prims for e in entries):
        uses = collect_bindings(open_stage(str(source))).uses
        for e in entries:
            if not e.bound_prims and e.prim in uses:
                e.bound_prims = list(uses[e.prim].renderable)
    documents = {m.name: m.document for m in load_asset(source, keep_going=True).materials}
    for e in entries:
        if e.prim in documents:
            e.textures = {str(p): b for p in document_textures(documents[e.prim])
                          if (b := texture_bytes(p)) is not None}


# ----------------------------------------------------------------------------- the scene and its renders


@dataclass
class SceneView:
    """The scene view of a layer (module docstring): images, FLIP, per-material entries, totals."""

    source: Path
    entries: list[SceneEntry]
    images: dict[str, np.ndarray]
    """:data:`IMAGES` -> [res, res, 3] float32 (renders linear; FLIP maps display-ready)."""
    ids: np.ndarray
    """[res, res] int: the entry index each pixel's centre ray first hits, -1 for the background."""
    flip: dict[str, float]
    """``{"neural", "preview"}``: HDR FLIP over the pixels that show a surface."""
    setup: dict
    """How it was viewed and lit (:attr:`.render.in_scene.InScene.record`)."""
    res: int
    spp: int
    seed: int
    seconds: float
    totals: dict = field(default_factory=dict)

    def numbers(self) -> dict:
        """JSON-ready figures (no images)."""
        return {"source": str(self.source), "flip": self.flip, "res": self.res, "spp": self.spp, "seed": self.seed,
                "seconds": self.seconds, "setup": self.setup, "totals": self.totals,
                "materials": [e.numbers() for e in self.entries]}


def scene_mesh(source: Path, entries: list[SceneEntry], res: int, seed: int):
    """The :class:`~mtlx2neural.render.in_scene.InScene` of every entry's bound meshes (one mesh; its
    ``material_index`` is each triangle's entry's index in ``entries``; camera and lights as
    :func:`.render.in_scene.setup_in_scene`; ``res`` pixels, ``seed`` the triangle subset's), or why there is
    none. Sets each entry's ``triangles``. Also the Mitsuba renderer's scene (:mod:`mtlx2neural.mitsuba.render`)."""
    # Local: reading a stage loads pxr, needed only for a stage's scene view.
    from mtlx2neural.scene.stage_render import read_stage_view
    from mtlx2neural.scene.usd_stage import open_stage

    stage = open_stage(str(source))
    views, index, notes = [], [], []
    for i, e in enumerate(entries):
        if not e.bound_prims:
            notes.append(f"{e.prim}: no bound mesh: not drawn")
            continue
        view = read_stage_view(stage, e.bound_prims)
        e.triangles = len(view.positions)
        views.append(view)
        index.append(np.full(len(view.positions), i, np.int64))
        notes += view.notes
    if not views or sum(len(v.positions) for v in views) == 0:
        return "no bound mesh could be read: " + ("; ".join(notes) or "none is bound")
    cat = (lambda name: np.concatenate([getattr(v, name) for v in views]))
    index = np.concatenate(index)
    keep = np.arange(len(index))
    if len(keep) > MAX_TRIANGLES:  # as setup_in_scene does, but keeping each triangle's material
        keep = np.sort(np.random.default_rng(seed).choice(len(keep), MAX_TRIANGLES, replace=False))
        notes.append(f"{len(index)} triangles: a seeded random {MAX_TRIANGLES} of them are drawn")
    view = dataclasses.replace(views[0], positions=cat("positions")[keep], uvs=cat("uvs")[keep],
                               normals=cat("normals")[keep], prims=[p for v in views for p in v.prims],
                               notes=list(dict.fromkeys(notes)))
    scene = setup_in_scene(view, res, max_triangles=len(keep), seed=seed)
    if not isinstance(scene, str):
        scene.geometry.material_index = torch.from_numpy(index[keep])
    return scene


def _flip(ref: np.ndarray, test: np.ndarray, ids: np.ndarray, count: int) -> tuple[float, np.ndarray, list]:
    """(FLIP over the shown pixels, magma map, per entry FLIP over its pixels or None)."""
    if float(ref.max()) <= 0:
        return math.nan, np.zeros_like(ref), [None] * count
    raw = hdr_flip(ref, test, apply_magma=False)[0][..., 0]
    fmap = hdr_flip(ref, test)[0]
    shown = (ref.sum(-1) > 0) | (test.sum(-1) > 0)
    per = [round(float(raw[ids == i].mean()), 4) if (ids == i).any() else None for i in range(count)]
    return (float(raw[shown].mean()) if shown.any() else 0.0), fmap, per


def totals(entries: list[SceneEntry]) -> dict:
    """Training time and memory over the layer (module docstring): ``train_seconds``, ``seconds``,
    ``shipped_memory``, ``shipped_disk``, ``shipped`` (by kind), ``source_textures`` (bytes), ``source_files``
    (count), ``ratio`` (shipped memory / source textures, None without textures)."""
    converted = [e for e in entries if e.status in ("converted", "flagged")]
    trained = [e.record for e in converted if not e.record.shared_with]
    exports, textures = {}, {}
    for e in converted:
        exports[str(e.folder)] = e.shipped
        textures.update(e.textures)
    shipped = {k: sum(s[k] for s in exports.values()) for k in ("latent", "weights", "surface", "memory", "disk")}
    source = sum(textures.values())
    return {"materials": len(entries), "converted": len(converted),
            "skipped": sum(e.status == "skipped" for e in entries),
            "missing": sum(e.status == "missing" for e in entries),
            "flagged": sum(e.status == "flagged" for e in entries),
            "train_seconds": round(sum(r.train_seconds for r in trained), 2),
            "seconds": round(sum(r.seconds for r in trained), 2),
            "shipped": shipped, "shipped_memory": shipped["memory"], "shipped_disk": shipped["disk"],
            "source_textures": source, "source_files": len(textures),
            "ratio": round(shipped["memory"] / source, 4) if source else None}


def scene_view(layer, res: int = RES, spp: int = SPP, seed: int = 0) -> SceneView | str:
    """The :class:`SceneView` of the neural ``layer`` (module docstring), or one line saying why there is
    none (a ``.mtlx`` input, no bound mesh)."""
    gathered = gather(Path(layer))
    if isinstance(gathered, str):
        return gathered
    source, entries = gathered
    t0 = time.time()
    scene = scene_mesh(source, entries, res, seed)
    if isinstance(scene, str):
        return scene
    texels = [e.texels for e in entries]
    env = any(isinstance(li, EnvironmentMap) for li in scene.lights)
    references = [e.models["reference"] for e in entries]
    images = {}
    for kind in ("reference", "neural", "preview"):
        images[kind] = render_scene([e.models[kind] for e in entries], scene.geometry, scene.camera, scene.lights,
                                    res, spp, texels, seed, sampler=references if env else None)
    centre, radius = scene.geometry.bounds()
    hits = scene.geometry.intersect(scene.camera.rays(res, centre, radius, torch.Generator().manual_seed(0)))
    ids = torch.where(hits.mask, hits.material, torch.full_like(hits.material, -1)).view(res, res).numpy()
    flip = {}
    per = {}
    for kind in ("neural", "preview"):
        flip[kind], images[f"{kind}_flip"], per[kind] = _flip(images["reference"], images[kind], ids, len(entries))
    for i, e in enumerate(entries):
        e.flip = {kind: per[kind][i] for kind in per}
    return SceneView(source, entries, images, ids, {k: round(v, 4) for k, v in flip.items()}, scene.record, res,
                     spp, seed, round(time.time() - t0, 2), totals(entries))
