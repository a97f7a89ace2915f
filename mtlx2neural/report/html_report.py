"""``mtlx2neural report OUT_neural.usda``: a self-contained HTML report of every neural material in a layer.

For each material of the layer (read back with :func:`mtlx2neural.load_neural`; its
training folder, its record ``summary.json`` (:func:`~mtlx2neural.material_record.read_record`)
and ``training_curves.csv`` are found beside the exported files) the report compares three models against the MaterialX reference
(:func:`mtlx2neural.load_reference` on the record's source asset):

- renders of reference / analytic baseline / neural at :data:`.render.VIEWS`, with HDR FLIP
  maps (:func:`.render.compare_many`: one reference render per view, the analytic and neural renders
  stored under their own names); the analytic baseline is fitted here
  (:func:`.analytic.fit_analytic`, ``analytic_iterations`` Adam steps);
- error versus cost: mean HDR FLIP against evaluations per second for the reference, the
  analytic fit and the decoders 2x16, 2x32 and 3x64 (:mod:`.cost_table`), measured as generated
  shaders on slangpy's CPU device, or with torch when slangpy is missing (lower-right is better);
- polar plots at chosen texels (default the centre, uv 0.5, 0.5) in the plane of incidence, wi 45 degrees
  off the normal: f*cos (luminance, log-compressed radius log1p(x/0.01), normalised) of
  the three models, and the sampling pdf (per steradian) of each model's own sampler;
- the training curves (every ``loss_*`` column of ``training_curves.csv`` against step);
- latent texture previews (channels 0-2 of each latent EXR's finest level, each channel
  min-max normalised) and the memory footprint: latent bytes at FP16 (all MIP levels, 4
  channels per EXR) and ``weights.bin``'s size.

A UDIM material (a neural model with trained tiles) is reported tile by tile: the analytic
baseline is fitted per trained tile (one [0,1]^2 map each, on that tile's stack), the renders show
each tile on the sphere (:class:`~mtlx2neural.render.udim_view.TileView`; FLIP is the mean over
tiles and views), the polar plots default to each trained tile's centre (``--texel`` takes true uv,
inside a trained tile), the latent previews show every tile's files, and the shader cost is timed on
a one-tile stand-in with the same decoder (the tile lookup is a few integer operations more).

A layer whose input is a USD stage first gets the scene view (:mod:`.scene_view`, :func:`scene_section`): the
stage from its camera with every material of the layer at once, rendered with the references, the neural
models and the UsdPreviewSurface previews, their HDR FLIP maps, a table of every material (FLIP, energy,
decoder, training time, shipped bytes, emission and opacity, status: converted, flagged or skipped) and the
totals (training time, shipped memory against the source textures'; conventions in :mod:`.scene_view`).
A ``.mtlx`` layer gets a one-line note instead.

The figures are computed in :mod:`.material_figures` (baseline fit, renders, polar slices, curves,
latents) and :mod:`.cost_table`; plots are inline SVG (:mod:`.svg_plots`, no plotting library);
images are PNGs in the report folder, next to ``index.html``. The folder is written into a temporary sibling and
swapped in whole, so an interrupted run leaves the previous report (or none).
"""

from __future__ import annotations

import html
import json
import math
import string
from importlib import resources
from pathlib import Path

import numpy as np

from mtlx2neural.errors import InputError
from mtlx2neural.export.load import load_neural, neural_prims
from mtlx2neural.export.usd_writer import register_schema
from mtlx2neural.material_record import (
    RECORD_FILE,
    MaterialRecord,
    read_record,
    record_path,
)
from mtlx2neural.pipeline.layout import read_layer_record
from mtlx2neural.pipeline.output_safety import (
    REPORT_MARKER,
    claim_report_folder,
    report_marker,
)
from mtlx2neural.reference.loading import application_of, load_reference
from mtlx2neural.render.renderer import VIEWS, save_png
from mtlx2neural.render.udim_view import model_tiles
from mtlx2neural.report.cost_table import cost_row, cost_table, size_trainer
from mtlx2neural.report.material_figures import (
    fit_and_render,
    latent_figures,
    polar_figures,
    training_curves_svg,
)
from mtlx2neural.report.scene_view import (
    OWN_MODELS,
    SceneView,
    scene_view,
    surface_kinds,
)
from mtlx2neural.report.svg_plots import svg_scatter
from mtlx2neural.scene.dependencies import input_files
from mtlx2neural.staging import Staging
from mtlx2neural.version import __version__

SECTIONS = ("Renders", "As a viewer shades it", "Error versus cost", "Polar plots", "Energy", "Training curves", "Latent textures", "Memory")


# ----------------------------------------------------------------------------- the report


def _materials(layer: Path) -> list[str]:
    """Prim paths of the neural materials in ``layer``; InputError naming it when there are none."""
    # Local: pxr loads its plugins on import; the report's other imports do not need them yet.
    from pxr import Tf, Usd

    register_schema()  # before USD's schema registry is first used
    if not layer.is_file():
        raise InputError(f"{layer}: no such file; give the _neural.usda layer that `mtlx2neural ASSET` wrote")
    try:
        stage = Usd.Stage.Open(str(layer), load=Usd.Stage.LoadNone)
    except Tf.ErrorException:
        raise InputError(f"{layer}: USD cannot open this layer; give the _neural.usda layer that "
                         f"`mtlx2neural ASSET` wrote") from None
    prims = neural_prims(stage) if stage else []
    if not prims:
        raise InputError(f"{layer}: holds no neural material; give the layer that `mtlx2neural ASSET` wrote")
    return [str(p.GetPath()) for p in prims]


def report_source(layer: Path, record: MaterialRecord) -> Path:
    """The input the reference is loaded from: the layer's own record of it (relative to the layer,
    so a moved pair of input and output still reports), else the material record's ``source``."""
    layer_record = read_layer_record(layer)
    if layer_record is not None and layer_record.source is not None:
        return layer_record.source
    return Path(record.source)


def _load_reference(record: MaterialRecord, folder: Path):
    """The conversion's reference, under the conversion's texture rules: a missing texture is an error
    unless the conversion itself allowed it (``--allow-missing-textures``, in the record's options)."""
    names = [n for n in (record.material, record.mtlx_material) if n]
    allow = bool((record.options or {}).get("allow_missing_textures", False))
    for i, name in enumerate(names):
        try:
            return load_reference(record.source, name, allow_missing_textures=allow,
                                  application=application_of(record.application))  # the conversion's --frame/--fps
        except InputError:
            if i == len(names) - 1:
                raise
    raise InputError(f"{record_path(folder)}: names no material")


def energy_table(record: MaterialRecord) -> str:
    """HTML of the conversion's energy check (the record's ``energy``): per MIP level, the reference's and
    the neural model's mean directional albedo (luminance) and their ratio; then each view angle's ratio
    averaged over the levels (records made before it was measured have none)."""
    energy = record.energy
    if not energy:
        return '<p class="note">Not measured at conversion (a UDIM material, or a record without it).</p>'
    rows = "".join(f'<tr><td class="l">{k}</td><td>{r:.3f}</td><td>{m:.3f}</td><td>{q:.2f}</td></tr>'
                   for k, (r, m, q) in enumerate(zip(energy["reference_by_level"], energy["model_by_level"],
                                                     energy["by_level"])))
    return (f'<p class="note">Directional albedo (luminance, mean over {energy["texels"]} texels x views '
            f'{", ".join(f"{d:g}" for d in energy["view_degrees"])} degrees): the neural model against the '
            f'reference filtered over each level\'s footprint. Lowest ratio {energy["min_ratio"]:.2f}; under 0.9 '
            f'the neural material renders visibly darker.</p><table><tr><th class="l">MIP level</th><th>reference'
            f'</th><th>neural</th><th>neural / reference</th></tr>{rows}</table>{_energy_by_view(energy)}')


def _energy_by_view(energy: dict) -> str:
    """A note with each view angle's energy ratio (the record's ``by_view``), or nothing."""
    ratios = energy.get("by_view")
    if not ratios:
        return ""
    views = ", ".join(f"{d:g}°: {q:.2f}" for d, q in zip(energy["view_degrees"], ratios))
    return (f'<p class="note">By view angle from the normal, neural / reference averaged over the levels: {views}. '
            f'The level ratios pool the views, so a model too dark at one angle and too bright at another can '
            f'still keep a level ratio near 1.</p>')


def viewer_section(record, folder: Path, out: Path, p: str) -> str:
    """The record's viewer figure (``flip_viewer``: the environment view shaded by the prefiltered path a viewer
    uses) with the conversion's images of it, copied into ``out`` as ``<p>viewer_*.png``; a note for a record
    without one."""
    if record.flip_viewer is None:
        return ('<h3>As a viewer shades it</h3><p class="note">Not measured: the model has no environment head (a '
                'viewer samples its BRDF, as the views above do), it is a UDIM material, or the conversion predates '
                'the figure.</p>')
    figs = []
    for kind, caption in (("reference", "reference"), ("neural", f"prefiltered, FLIP {record.flip_viewer:.4f}"),
                          ("flip", "FLIP map")):
        src = folder / f"viewer_{kind}.png"
        if src.is_file():
            (out / f"{p}viewer_{kind}.png").write_bytes(src.read_bytes())
            figs.append(f'<figure><img src="{p}viewer_{kind}.png" alt="viewer {kind}"><figcaption>viewer: {caption}'
                        f"</figcaption></figure>")
    sampled = record.flip_per_view[-1] if record.flip_per_view else None
    return (f'<h3>As a viewer shades it</h3><p class="note">{html.escape(record.flip_viewer_view)}. HDR FLIP '
            f'{record.flip_viewer:.4f}, against {_num(sampled)} for the same view with the BRDF sampled (the '
            f'views above): what a MaterialX viewer shows under an environment, where a path tracer shows the '
            f'latter.</p><div class="grid">{"".join(figs)}</div>')


def material_section(layer: Path, prim: str, out: Path, index: int, analytic_iterations: int, res: int,
                     spp: int, seed: int, texels_at=None, train_sizes: bool = False) -> tuple[str, dict]:
    """HTML of one material's report (images written into ``out``) and its numbers. ``texels_at``: the
    polar plots' uv (None: (0.5, 0.5), or each trained tile's centre for a UDIM material)."""

    neural = load_neural(layer, prim)
    weights = Path(neural.usd_info["weights"])
    folder = weights.parent.parent
    if not record_path(folder).is_file():
        raise InputError(f"{layer}: {prim}: no {RECORD_FILE} in {folder}; keep the conversion's output folder "
                         f"next to the layer")
    record = read_record(folder)
    record.source = str(report_source(layer, record))  # where the input is now, by the layer's record
    reference = _load_reference(record, folder)
    texels = tuple(record.resolution)
    tiles = model_tiles(neural)
    fitted = fit_and_render(reference, neural, texels, tiles, analytic_iterations, res, spp, seed)
    analytic, renders, fit_seconds = fitted.analytic, fitted.renders, fitted.fit_seconds
    p = f"m{index}_"
    res_n, res_a = renders["neural"], renders["analytic"]
    rows = []
    for i, (en, ea) in enumerate(zip(res_n, res_a)):
        save_png(out / f"{p}view{i}_reference.png", en["reference"])
        save_png(out / f"{p}view{i}_analytic.png", ea["analytic"])
        save_png(out / f"{p}view{i}_neural.png", en["neural"])
        save_png(out / f"{p}view{i}_analytic_flip.png", ea["flip_map"], linear=False)
        save_png(out / f"{p}view{i}_neural_flip.png", en["flip_map"], linear=False)
        figs = [("reference", "reference"), ("analytic", f"analytic, FLIP {ea['flip']:.4f}"),
                ("neural", f"neural, FLIP {en['flip']:.4f}"), ("analytic_flip", "analytic FLIP map"),
                ("neural_flip", "neural FLIP map")]
        view = f"tile {en['tile']}, view {i % len(VIEWS)}" if tiles else f"view {i}"
        rows.append("".join(f'<figure><img src="{p}view{i}_{k}.png" alt="{k} {view}"><figcaption>{view}: '
                            f"{c}</figcaption></figure>" for k, c in figs))
    flip = {"analytic": float(np.mean([e["flip"] for e in res_a])), "neural": float(np.mean([e["flip"] for e in res_n])),
            "reference": 0.0}
    trained = record.decoder

    train_size = size_trainer(record, reference, fitted.stack, texels, tiles, res, spp) if train_sizes else None
    cost = cost_table(record, reference, analytic, neural, trained, flip, train_size)
    polar = polar_figures(reference, fitted, neural, tiles, texels_at, prim)
    curves_svg = training_curves_svg(folder)
    latents, latent_bytes = latent_figures(neural, tiles, out, p)
    weight_bytes = weights.stat().st_size
    e = html.escape
    numbers = {"material": prim, "flip": flip, "flip_viewer": record.flip_viewer, "cost": cost, "energy": record.energy, "latent_bytes": latent_bytes,
               "weight_bytes": weight_bytes, "analytic_fit_seconds": round(fit_seconds, 2),
               "analytic_final_loss": analytic.final_loss, "udim_tiles": tiles}
    cost_rows = "".join(cost_row(r) for r in cost["rows"])
    points = [(r["model"], r["rate"], r["flip"]) for r in cost["rows"] if r["rate"] and r["flip"] is not None]
    udim_note = (f" per UDIM tile, tiles {', '.join(map(str, tiles))} (the analytic baseline is fitted per tile; costs "
                 f"are timed on one tile)") if tiles else ""
    body = f"""
<h2 id="material-{index}">{e(record.material)} <small>({e(prim)})</small></h2>
<p class="note">Source {e(record.source)}; decoder {e(record.decoder)}, {record.steps}
steps in {record.train_seconds} s on {e(record.device_name)};
latent grid {texels[1]}x{texels[0]}{udim_note}. Analytic baseline: {analytic_iterations} Adam steps in {fit_seconds:.1f} s,
final log-L1 {analytic.final_loss:.4f}{' (first tile)' if tiles else ''}.</p>
<h3>Renders</h3>
<p class="note">Orthographic sphere, one directional light per view, {res}x{res} px, {spp} spp; FLIP is HDR FLIP
against the reference render{'; each trained UDIM tile on the sphere (its uv shifted to the tile), mean over tiles and views' if tiles else ''}.</p>
<div class="grid">{''.join(rows)}</div>
{viewer_section(record, folder, out, p)}
<h3>Error versus cost</h3>
<p class="note">{e(cost["how"])}</p>
<table><tr><th class="l">model</th><th>mean HDR FLIP</th><th>evals/s ({e(cost["harness"])})</th><th class="l">note</th></tr>
{cost_rows}</table>
<div class="plots">{svg_scatter(points, f"evaluations per second ({cost['harness']})", "mean HDR FLIP")}</div>
<h3>Polar plots</h3>
<p class="note">Plane of incidence, wi 45 degrees from the normal (coming from the left); radius log1p(x/0.01),
normalised; at each chosen texel (<code>--texel U,V</code>).</p>
{''.join(polar)}
<h3>Energy</h3>
{energy_table(record)}
<h3>Training curves</h3>
<p class="note">Losses against step; where the conversion probed its quality (<code>probe_every</code>), HDR FLIP
against training seconds (three views at 48², 4 samples per pixel, so noisier than the table's figure).</p>
<div class="plots">{curves_svg}</div>
<h3>Latent textures</h3>
<div class="latents">{''.join(latents)}</div>
<h3>Memory</h3>
<table><tr><th class="l">what</th><th>bytes</th></tr>
<tr><td class="l">latent textures (FP16, all MIP levels)</td><td>{latent_bytes}</td></tr>
<tr><td class="l">weights.bin (FP16)</td><td>{weight_bytes}</td></tr>
<tr><td class="l">total</td><td>{latent_bytes + weight_bytes}</td></tr></table>
"""
    return body, numbers


def _num(x, digits: int = 4) -> str:
    """``x`` with ``digits`` decimals; a dash for a missing figure (None or NaN)."""
    return "&ndash;" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _pair(a, b) -> str:
    return f"{_num(a)} / {_num(b)}"


def _status(entry) -> str:
    e = html.escape
    text = {"converted": "converted", "flagged": "flagged by the quality gate", "skipped": "skipped by the conversion",
            "missing": "neural model missing"}[entry.status]
    why = f"<br><small>{e(entry.reason)}</small>" if entry.reason else ""
    drawn = "" if entry.drawn == OWN_MODELS else f"<br><small><i>drawn with {e(entry.drawn)}</i></small>"
    return f'<td class="l status-{entry.status}"><b>{text}</b>{why}{drawn}</td>'


def _scene_row(entry) -> str:
    r, s = entry.record, entry.shipped or {}
    kinds = surface_kinds(r)
    surface = [f"emission: {kinds['emission']}" if kinds["emission"] != "none" else "",
               f"opacity: {kinds['opacity']}" + (f" ({kinds['alpha_mode']})" if kinds["alpha_mode"] != "opaque" else "")
               if kinds["opacity"] != "none" else ""]
    surface = ", ".join(x for x in surface if x) or "no emission, opaque"
    cells = [f'<td class="l">{html.escape(entry.prim)}<br><small>{surface}</small></td>', _status(entry)]
    if r is None:
        cells += ['<td colspan="6">&ndash;</td>']
    else:
        cells += [f"<td>{_pair(r.flip_mean, r.preview_flip)}</td>",
                  f"<td>{_pair(r.flip_in_scene, r.preview_flip_in_scene)}</td>",
                  f"<td>{_pair(entry.flip.get('neural'), entry.flip.get('preview'))}</td>",
                  f"<td>{_num((r.energy or {}).get('min_ratio'), 2)}</td>",
                  f"<td>{html.escape(r.decoder)}</td>", f"<td>{r.train_seconds:.1f}</td>"]
    b = (lambda k: f"{s[k]:,}" if k in s else "&ndash;")
    cells += [f"<td>{b('latent')}</td>", f"<td>{b('weights')}</td>", f"<td>{b('surface')}</td>",
              f"<td>{sum(entry.textures.values()):,}</td>"]
    return "<tr>" + "".join(cells) + "</tr>"


def scene_section(layer: Path, out: Path, res: int, spp: int, seed: int) -> tuple[str, dict | str]:
    """HTML of the scene view (:mod:`.scene_view`; images ``scene_*.png`` written into ``out``) and its
    numbers, or a one-line note and why there is none."""
    view = scene_view(layer, res, spp, seed)
    if not isinstance(view, SceneView):
        return f'<p class="note">No scene view: {html.escape(view)}.</p>', view
    e = html.escape
    for name, img in view.images.items():
        save_png(out / f"scene_{name}.png", img, linear=not name.endswith("_flip"))
    f = view.flip
    figs = [("reference", "reference (MaterialX)"), ("neural", f"neural, FLIP {f['neural']:.4f}"),
            ("preview", f"UsdPreviewSurface preview, FLIP {f['preview']:.4f}"),
            ("neural_flip", "neural FLIP map"), ("preview_flip", "preview FLIP map")]
    images = "".join(f'<figure><img class="scene" src="scene_{k}.png" alt="scene {k}"><figcaption>{c}</figcaption>'
                     f"</figure>" for k, c in figs)
    t = view.totals
    ratio = f"{t['ratio']:.2f}x" if t["ratio"] is not None else "&ndash; (no source texture)"
    setup = view.setup
    notes = "".join(f"<li>{e(n)}</li>" for n in setup.get("notes", []))
    rows = "".join(_scene_row(x) for x in view.entries)
    mib = (lambda n: f"{n / 2**20:.2f} MiB ({n:,} bytes)")
    body = f"""
<h2 id="scene">Scene <small>({e(str(view.source))})</small></h2>
<p class="note">Every material of the layer on its bound meshes, seen by {e(setup['camera'])}, lit by
{e('; '.join(setup['lights']))}; {view.res}x{view.res} px, {view.spp} spp, seed {view.seed}, {setup['triangles']}
triangles, the same random numbers in all three renders ({view.seconds:.1f} s). FLIP: HDR FLIP against the
reference over the pixels that show a surface. {t['converted']} converted ({t['flagged']} flagged),
{t['skipped']} skipped, {t['missing']} with no readable neural model (drawn with their reference).</p>
{'<ul class="note">' + notes + '</ul>' if notes else ''}
<div class="grid">{images}</div>
<table class="scene">
<tr><th class="l">material<br><small>emission, opacity</small></th><th class="l">status</th><th>HDR FLIP<br>sphere views</th>
<th>HDR FLIP<br>in scene</th><th>HDR FLIP<br>this render</th><th>energy<br>kept</th>
<th>decoder</th><th>training<br>(s)</th><th>latents<br>(bytes)</th><th>weights<br>(bytes)</th><th>emission,<br>opacity (bytes)</th>
<th>source<br>textures (bytes)</th></tr>
{rows}</table>
<table class="scene">
<tr><th class="l">totals</th><th></th></tr>
<tr><td class="l">training time (sum of the materials' optimisation; whole conversions)</td>
<td>{t['train_seconds']:.1f} s ({t['seconds']:.1f} s)</td></tr>
<tr><td class="l">shipped: latents + weights + emission/opacity maps, in memory</td><td>{mib(t['shipped_memory'])}</td></tr>
<tr><td class="l">shipped, on disk (file sizes)</td><td>{mib(t['shipped_disk'])}</td></tr>
<tr><td class="l">source textures of the converted materials ({t['source_files']} files), decoded with MIP chains</td>
<td>{mib(t['source_textures'])}</td></tr>
<tr><td class="l">shipped memory / source textures</td><td>{ratio}</td></tr></table>
<p class="note">HDR FLIP columns: neural / preview. <i>Sphere views</i> and <i>in scene</i> (the material alone
on its meshes, from the stage's camera) are the conversion's figures; <i>this render</i> is over the material's own
pixels in the images above. <i>Energy kept</i>: the lowest ratio, over MIP levels, of the neural model's directional
albedo to the reference's. Bytes in memory: an EXR counts every stored MIP level at its stored bytes per channel (half: 2), a
DDS its block data, weights.bin its size. Source textures count width x height x channels x bytes per channel of
the file (8-bit: 1, half: 2, float: 4) plus a third for a MIP chain; a file read by several materials counts once;
skipped materials' textures are left out (they ship as before). Training time: the records'
<code>train_seconds</code> (<code>seconds</code>: the whole conversion of each material).</p>
"""
    return body, view.numbers()


def default_report_dir(layer) -> Path:
    layer = Path(layer).resolve()
    return layer.parent / f"{layer.stem}_report"


def write_report(layer, out=None, analytic_iterations: int = 300, res: int = 96, spp: int = 8,
                 seed: int = 0, scene_res: int = 128, scene_spp: int = 16, materials: list[str] | None = None,
                 texels_at=None, train_sizes: bool = False) -> dict:
    """Write ``out/index.html`` (default ``<layer stem>_report/`` beside the layer) and its PNGs.

    A USD input's report starts with the scene view (:func:`scene_section`, ``scene_res`` x ``scene_res``
    pixels, ``scene_spp`` samples per pixel; ``scene_res=0`` leaves it out), its numbers in ``scene.json``.

    ``materials`` restricts the report to these prim paths; ``texels_at`` lists the (u, v)
    texture coordinates of the polar plots (default the centre, (0.5, 0.5)); ``train_sizes``
    trains the decoder sizes whose FLIP the conversion did not measure (:func:`cost_table`). Returns ``{"html": Path,
    "materials": [per-material numbers], "scene": the scene view's numbers, or why there is none}``. Raises :class:`~mtlx2neural.errors.InputError` for a
    missing or invalid layer.
    """
    layer = Path(layer).resolve()
    prims = _materials(layer)
    if materials:
        chosen = [p for p in prims if p in materials or p.rsplit("/", 1)[-1] in materials]
        if not chosen:
            raise InputError(f"{layer}: no neural material named {', '.join(materials)}; it holds {', '.join(prims)}")
        prims = chosen
    out = Path(out).resolve() if out else default_report_dir(layer)
    claim_report_folder(out, input_files(layer), layer)  # empty, new, or an earlier report; never an input
    with Staging(out.parent) as st:  # the whole report folder appears at once, or not at all
        tmp = st.stage(out)
        (tmp / REPORT_MARKER).write_text(report_marker(layer, __version__))
        if scene_res > 0:
            scene_body, scene = scene_section(layer, tmp, scene_res, scene_spp, seed)
        else:
            scene_body, scene = '<p class="note">No scene view (scene resolution 0).</p>', "left out (scene_res 0)"
        bodies, numbers = [], []
        for i, prim in enumerate(prims):
            b, n = material_section(layer, prim, tmp, i, analytic_iterations, res, spp, seed,
                                    tuple(texels_at) if texels_at else None, train_sizes)
            bodies.append(b)
            numbers.append(n)
        template = string.Template(resources.files(__package__).joinpath("report_template.html").read_text())
        toc = "".join(f'<li><a href="#material-{i}">{html.escape(p)}</a></li>' for i, p in enumerate(prims))
        page = template.substitute(
            title=html.escape(f"mtlx2neural report: {layer.name}"),
            intro=html.escape(f"{len(prims)} neural material(s) in {layer}; reference = MaterialX reference BRDF, "
                              f"analytic = Lambert + GGX fitted with {analytic_iterations} steps, neural = the "
                              f"exported model (FP16 latents and weights)."),
            body=scene_body + f"<ul>{toc}</ul>" + "".join(bodies))
        (tmp / "index.html").write_text(page)
        (tmp / "report.json").write_text(json.dumps(numbers, indent=2))
        (tmp / "scene.json").write_text(json.dumps(scene, indent=2))
    return {"html": out / "index.html", "materials": numbers, "scene": scene}
