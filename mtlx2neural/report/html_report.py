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
  analytic fit and the decoders 2x16, 2x32 and 3x64 (:func:`cost_table`), measured as generated
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

Plots are inline SVG written here (no plotting library needed); images are PNGs in the
report folder, next to ``index.html``. The folder is written into a temporary sibling and
swapped in whole, so an interrupted run leaves the previous report (or none).
"""

from __future__ import annotations

import csv
import html
import json
import math
import string
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.baseline.analytic_model import fit_analytic
from mtlx2neural.contract import Material, ShadingPoint
from mtlx2neural.errors import InputError
from mtlx2neural.export.load import _neural_prims, load_neural
from mtlx2neural.export.usd_writer import register_schema
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.imaging.udim import tile_of_udim, udim_at
from mtlx2neural.material_record import (
    RECORD_FILE,
    MaterialRecord,
    read_record,
    record_path,
)
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.pipeline.layout import read_layer_record
from mtlx2neural.pipeline.output_safety import (
    REPORT_MARKER,
    claim_report_folder,
    report_marker,
)
from mtlx2neural.pipeline.plan import DECODERS
from mtlx2neural.reference.loading import application_of, load_reference
from mtlx2neural.render.renderer import VIEWS, compare, compare_many, save_png
from mtlx2neural.render.udim_view import TileView, compare_tiles, model_tiles
from mtlx2neural.report.shader_cost import shader_available, shader_rates
from mtlx2neural.scene import find_material
from mtlx2neural.scene.dependencies import input_files
from mtlx2neural.staging import Staging
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.directions import half_difference_pairs
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.train.udim import build_tiled_stack
from mtlx2neural.version import __version__

COLOURS = {"reference": "#222222", "analytic": "#d95f02", "neural": "#1b9e77", "reference sampler": "#7570b3",
           "analytic sampler": "#e7298a", "neural sampler": "#1b9e77"}
SECTIONS = ("Renders", "Error versus cost", "Polar plots", "Training curves", "Latent textures", "Memory")


# ----------------------------------------------------------------------------- SVG plots


def _ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    return [lo + (hi - lo) * i / (n - 1) for i in range(n)]


def _axes(w, h, m, xr, yr, xlabel, ylabel, xfmt, yfmt) -> list[str]:
    out = [f'<rect x="{m}" y="{m // 2}" width="{w - 1.5 * m}" height="{h - 1.5 * m}" fill="none" stroke="#999"/>']
    for t in _ticks(*xr):
        x = m + (t - xr[0]) / (xr[1] - xr[0] or 1) * (w - 1.5 * m)
        out.append(f'<text x="{x:.1f}" y="{h - m + 16}" font-size="10" text-anchor="middle">{xfmt(t)}</text>')
    for t in _ticks(*yr):
        y = h - m - (t - yr[0]) / (yr[1] - yr[0] or 1) * (h - 1.5 * m)
        out.append(f'<text x="{m - 4}" y="{y + 3:.1f}" font-size="10" text-anchor="end">{yfmt(t)}</text>')
    out.append(f'<text x="{w / 2}" y="{h - 6}" font-size="12" text-anchor="middle">{html.escape(xlabel)}</text>')
    out.append(f'<text x="12" y="{h / 2}" font-size="12" text-anchor="middle" '
               f'transform="rotate(-90 12 {h / 2})">{html.escape(ylabel)}</text>')
    return out


def svg_lines(series: dict, xlabel: str, ylabel: str, logy: bool = False, w: int = 520, h: int = 320) -> str:
    """Line plot of ``{name: (xs, ys)}``; ``logy`` plots log10(y) (y clamped to 1e-12)."""
    m = 60
    tf = (lambda v: math.log10(max(v, 1e-12))) if logy else float
    pts = {k: [(float(x), tf(y)) for x, y in zip(*v) if math.isfinite(float(y))] for k, v in series.items()}
    allp = [p for v in pts.values() for p in v] or [(0.0, 0.0), (1.0, 1.0)]
    xr = (min(p[0] for p in allp), max(p[0] for p in allp))
    yr = (min(p[1] for p in allp), max(p[1] for p in allp))
    yr = yr if yr[1] > yr[0] else (yr[0] - 0.5, yr[1] + 0.5)
    xr = xr if xr[1] > xr[0] else (xr[0] - 0.5, xr[1] + 0.5)
    out = _axes(w, h, m, xr, yr, xlabel, ylabel, lambda t: f"{t:.0f}",
                (lambda t: f"{10 ** t:.2g}") if logy else (lambda t: f"{t:.3g}"))
    palette = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02"]
    for i, (name, p) in enumerate(pts.items()):
        c = COLOURS.get(name, palette[i % len(palette)])
        xy = " ".join(f"{m + (x - xr[0]) / (xr[1] - xr[0]) * (w - 1.5 * m):.1f},"
                      f"{h - m - (y - yr[0]) / (yr[1] - yr[0]) * (h - 1.5 * m):.1f}" for x, y in p)
        out.append(f'<polyline points="{xy}" fill="none" stroke="{c}" stroke-width="1.5"/>')
        out.append(f'<text x="{w - m}" y="{m // 2 + 14 + 14 * i}" font-size="11" fill="{c}" '
                   f'text-anchor="end">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


def svg_scatter(points: list, xlabel: str, ylabel: str, w: int = 520, h: int = 320) -> str:
    """Labelled points ``[(name, x, y)]`` with x on a log10 axis (x > 0)."""
    m = 60
    lx = [math.log10(max(x, 1e-12)) for _, x, _ in points]
    xr = (math.floor(min(lx)), math.ceil(max(lx)) if max(lx) > math.floor(min(lx)) else math.floor(min(lx)) + 1)
    yr = (0.0, max(max(y for _, _, y in points) * 1.15, 1e-3))
    out = _axes(w, h, m, xr, yr, xlabel, ylabel, lambda t: f"1e{t:.1f}", lambda t: f"{t:.3f}")
    for (name, _, y), x in zip(points, lx):
        px = m + (x - xr[0]) / (xr[1] - xr[0]) * (w - 1.5 * m)
        py = h - m - (y - yr[0]) / (yr[1] - yr[0]) * (h - 1.5 * m)
        c = COLOURS.get(name, "#333")
        out.append(f'<circle cx="{px:.1f}" cy="{py:.1f}" r="5" fill="{c}"/>')
        out.append(f'<text x="{px + 7:.1f}" y="{py - 7:.1f}" font-size="11" fill="{c}">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


def svg_polar(series: dict, title: str, w: int = 420, eps: float = 1e-2) -> str:
    """Upper half-plane polar plot of ``{name: (theta [rad from the normal, signed], value >= 0)}``;
    radius log1p(value/eps) normalised to the largest over all series."""
    h = w // 2 + 40
    cx, cy, r0 = w / 2, w / 2 + 10, w / 2 - 20
    top = max([float(np.log1p(np.max(v) / eps)) for _, v in series.values()] + [1e-6])
    out = [f'<text x="{cx}" y="14" font-size="12" text-anchor="middle">{html.escape(title)}</text>']
    for f in (0.25, 0.5, 0.75, 1.0):
        out.append(f'<path d="M {cx - r0 * f} {cy} A {r0 * f} {r0 * f} 0 0 1 {cx + r0 * f} {cy}" fill="none" '
                   f'stroke="#ddd"/>')
    out.append(f'<line x1="{cx - r0}" y1="{cy}" x2="{cx + r0}" y2="{cy}" stroke="#999"/>')
    out.append(f'<line x1="{cx}" y1="{cy}" x2="{cx}" y2="{cy - r0}" stroke="#ddd"/>')
    for i, (name, (theta, v)) in enumerate(series.items()):
        r = np.log1p(np.clip(np.nan_to_num(v), 0, None) / eps) / top * r0
        xy = " ".join(f"{cx + rr * math.sin(t):.1f},{cy - rr * math.cos(t):.1f}" for t, rr in zip(theta, r))
        c = COLOURS.get(name, "#333")
        out.append(f'<polyline points="{xy}" fill="none" stroke="{c}" stroke-width="1.5"/>')
        out.append(f'<text x="8" y="{30 + 14 * i}" font-size="11" fill="{c}">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


# ----------------------------------------------------------------------------- measurements


def evals_per_second(material: Material, n: int = 16384, repeats: int = 3, seed: int = 0) -> float:
    """Evaluations per second of ``material.eval(wi, wo, ShadingPoint(uv=uv))`` on ``n`` random pairs
    (local frame, half/difference angles) at random uv (best of ``repeats``)."""

    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = torch.rand(n, 2, generator=g)
    best = math.inf
    with torch.no_grad():
        material.eval(wi[:64], wo[:64], ShadingPoint(uv=uv[:64]))  # warm-up
        for _ in range(repeats):
            t = time.perf_counter()
            material.eval(wi, wo, ShadingPoint(uv=uv))
            best = min(best, time.perf_counter() - t)
    return n / max(best, 1e-9)


def _cost_row(r: dict) -> str:
    flip = "-" if r["flip"] is None else f"{r['flip']:.4f}"
    rate = "-" if r["rate"] is None else f"{r['rate']:.3g}"
    return (f'<tr><td class="l">{html.escape(r["model"])}</td><td>{flip}</td><td>{rate}</td>'
            f'<td class="l">{html.escape(r["note"])}</td></tr>')


def _mtlx_source(record: MaterialRecord):
    """The record's material as a MaterialSource (for MaterialX's own shader), or None."""
    for name in (record.material, record.mtlx_material):
        if name:
            try:
                return find_material(record.source, name)
            except InputError:
                continue
    return None


def one_tile_stand_in(neural):
    """``neural`` itself, or for a UDIM model a model without tiles holding its first tile's latents
    and the same decoder and sampler weights: what :func:`cost_table` times (a lookup at uv in
    [0,1]^2 would miss a UDIM model's tiles; the cost per evaluation does not depend on the tile)."""
    if not model_tiles(neural):
        return neural
    dec = neural.decoder
    one = NeuralMaterial(tuple(neural.latents.levels[0].shape[-2:]), in_dim=0, latent_dim=dec.latent_dim,
                         frames=dec.frames, decoder=tuple(dec.hidden),
                         albedo_head=dec.albedo is not None, analytic_cosine=dec.analytic_cosine)
    state = {k: v for k, v in neural.state_dict().items() if k.startswith(("decoder.", "sampler."))}
    one.load_state_dict(state, strict=False)
    with torch.no_grad():
        for a, b in zip(one.latents.levels, neural.latents.levels):
            a.copy_(b[0])
    return one.train(False)


def cost_table(record: MaterialRecord, reference, analytic, neural, trained: str, flip: dict, train_sizes=None) -> dict:
    """Rows (model, mean HDR FLIP or None, evals/s or None, note) for the reference, the analytic
    baseline and every decoder size of the error budget, with the harness used.

    Costs come from :func:`.shader_cost.shader_rates` (generated shaders on slangpy's CPU device;
    sizes other than the trained one are timed with seeded weights, as cost does not depend on
    them), else from torch ``eval``. FLIP: measured here for the reference (0), the analytic fit
    and the trained decoder; for the other sizes, the conversion's budget run (``summary.json``,
    same views at the conversion's spp) when it tried them; else, with ``train_sizes`` (a function
    decoder -> (model, FLIP)), trained for the report with the conversion's settings; else unknown."""

    budget = (record.budget or {}).get("flip_by_decoder", {})
    neural = one_tile_stand_in(neural)  # costs only: a UDIM model is timed as one tile
    sizes, fresh = {trained: neural}, {}
    for d in DECODERS:
        if d != trained and d not in budget and train_sizes is not None:
            model, fresh[d] = train_sizes(d)
            sizes[d] = one_tile_stand_in(model)
        elif d != trained:
            torch.manual_seed(0)
            sizes[d] = type(neural)(tuple(neural.latents.levels[0].shape[1:]), in_dim=0,
                                    latent_dim=neural.decoder.latent_dim, frames=neural.decoder.frames, decoder=d)
            with torch.no_grad():
                for a, b in zip(sizes[d].latents.levels, neural.latents.levels):
                    a.copy_(b)
    ok, why = shader_available()
    if ok:
        rates = shader_rates(sizes, analytic, _mtlx_source(record))
        harness = "generated shaders, slangpy CPU"
        how = ("Evaluations per second of the code a renderer runs, on slangpy's CPU device (FP32): MaterialX's own "
               "Slang for the reference, codegen/slang/AnalyticMaterial.slang for the analytic fit and each decoder's "
               "generated module, the last two including their texture-pyramid fetch. CPU figures rank the models; "
               "they do not predict GPU times.")
    else:
        rates = {"reference": evals_per_second(reference), "analytic": evals_per_second(analytic),
                 trained: evals_per_second(neural)}
        harness = "torch, CPU"
        how = f"Shader harness unavailable ({why}): evaluations per second of the torch models instead."
    rows = [{"model": "reference", "flip": 0.0, "rate": rates.get("reference"),
             "note": rates.get("reference_note", "MaterialX's generated code")},
            {"model": "analytic (Lambert + GGX)", "flip": flip["analytic"], "rate": rates.get("analytic"),
             "note": "fitted for this report"}]
    for d in sizes:
        if d == trained:
            f, note = flip["neural"], "the exported model"
        elif d in budget:
            f, note = float(budget[d]), "FLIP from the conversion's error-budget run"
        elif d in fresh:
            f, note = fresh[d], "trained for this report with the conversion's settings (--train-sizes)"
        else:
            f, note = None, "not trained (report --train-sizes, or convert with --max-error, trains it)"
        rows.append({"model": f"neural {d}", "flip": f, "rate": rates.get(d), "note": note})
    return {"harness": harness, "how": how, "rows": rows}


def polar_slices(reference, analytic, neural, theta_i_deg: float = 45.0, steps: int = 179, uv=(0.5, 0.5)):
    """(theta_o [rad], {model: luminance f*cos}, {sampler: pdf [1/sr]}) in the plane of incidence (x-z
    of the local frame, wi at ``theta_i_deg`` on the -x side) at texture coordinate ``uv``, finest
    level; f*cos includes the cosine, as ``eval`` does. Every model is a Material queried through
    ``eval``/``pdf``: the pdfs are the neural sampler's, the reference's and the analytic model's."""
    lum = torch.tensor([0.2126, 0.7152, 0.0722])
    t = torch.linspace(-math.pi / 2 + 0.01, math.pi / 2 - 0.01, steps)
    ti = math.radians(theta_i_deg)
    wi = torch.tensor([[-math.sin(ti), 0.0, math.cos(ti)]]).expand(steps, 3).contiguous()
    wo = torch.stack([t.sin(), torch.zeros_like(t), t.cos()], -1)
    at = ShadingPoint(uv=torch.tensor([[float(uv[0]), float(uv[1])]]).expand(steps, 2).contiguous())
    models = {"reference": reference, "analytic": analytic, "neural": neural}
    samplers = {"neural sampler": neural, "reference sampler": reference, "analytic sampler": analytic}
    with torch.no_grad():
        f = {k: m.eval(wi, wo, at) for k, m in models.items()}
        pdf = {k: m.pdf(wi, wo, at) for k, m in samplers.items()}
    return t.numpy(), {k: (v * lum).sum(-1).numpy() for k, v in f.items()}, {k: v.numpy() for k, v in pdf.items()}


def _normalised(img: np.ndarray) -> np.ndarray:
    x = img.astype(np.float32)
    lo, hi = x.min(axis=(0, 1), keepdims=True), x.max(axis=(0, 1), keepdims=True)
    return np.where(hi > lo, (x - lo) / np.maximum(hi - lo, 1e-12), 0.5)


# ----------------------------------------------------------------------------- the report


def _materials(layer: Path) -> list[str]:
    from pxr import Tf, Usd


    register_schema()  # before USD's schema registry is first used
    if not layer.is_file():
        raise InputError(f"{layer}: no such file; give the _neural.usda layer that `mtlx2neural ASSET` wrote")
    try:
        stage = Usd.Stage.Open(str(layer), load=Usd.Stage.LoadNone)
    except Tf.ErrorException:
        raise InputError(f"{layer}: USD cannot open this layer; give the _neural.usda layer that "
                         f"`mtlx2neural ASSET` wrote") from None
    prims = _neural_prims(stage) if stage else []
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
    t0 = time.time()
    if tiles:  # one analytic fit per trained tile, on that tile's stack; the sphere shows each tile
        tiled = build_tiled_stack(reference.compiled, tiles, texels)
        stack = tiled
        analytics = {t: fit_analytic(TileView(reference, t), st, iterations=analytic_iterations, batch=2048,
                                     seed=seed) for t, st in zip(tiles, tiled.stacks)}
        analytic = analytics[tiles[0]]
        renders = {"neural": [], "analytic": []}
        for t in tiles:
            per = compare_many(TileView(reference, t), {"neural": TileView(neural, t), "analytic": analytics[t]},
                               texels, res=res, spp=spp)
            for k in renders:
                renders[k] += [{**r, "tile": t} for r in per[k]]
    else:
        stack = build_parameter_stack(reference.compiled, resolution=texels)
        analytic = fit_analytic(reference, stack, iterations=analytic_iterations, batch=2048, seed=seed)
        analytics = None
        renders = compare_many(reference, {"neural": neural, "analytic": analytic}, texels, res=res, spp=spp)
    fit_seconds = time.time() - t0
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

    def train_size(decoder: str):
        """Train ``decoder`` with the conversion's settings; (model, mean HDR FLIP as above)."""
        cfg = TrainConfig(**{**record.config, "decoder": decoder, "compile": False})
        with tempfile.TemporaryDirectory(prefix="m2n_report_") as tmp_dir:
            model = Trainer(reference, stack, cfg, tmp_dir).run(progress=False)
        if tiles:
            errs = compare_tiles(reference, {"neural": model}, texels, tiles, res=res, spp=spp)["neural"]
        else:
            errs = compare(reference, model, texels, res=res, spp=spp)
        return model, float(np.mean([e["flip"] for e in errs]))

    cost = cost_table(record, reference, analytic, neural, trained, flip, train_size if train_sizes else None)
    polar = []
    if texels_at is None:
        texels_at = [(tu + 0.5, tv + 0.5) for tu, tv in map(tile_of_udim, tiles)] if tiles else [(0.5, 0.5)]
    for u, v in texels_at:
        if tiles:  # the tile holding (u, v): its analytic fit at local uv, the others at true uv
            t = udim_at(u, v)
            if t not in tiles:
                raise InputError(f"--texel {u:g},{v:g}: not in a UDIM tile {prim} was trained on ({tiles})")
            tu, tv = tile_of_udim(t)
            theta, brdf, pdf = polar_slices(TileView(reference, t), analytics[t], TileView(neural, t),
                                            uv=(u - tu, v - tv))
        else:
            theta, brdf, pdf = polar_slices(reference, analytic, neural, uv=(u, v))
        polar.append(f'<p class="note">uv ({u:g}, {v:g})</p><div class="plots">'
                     f'{svg_polar({k: (theta, x) for k, x in brdf.items()}, "f*cos (luminance)")}\n'
                     f'{svg_polar({k: (theta, x) for k, x in pdf.items()}, "sampling pdf (1/sr)")}</div>')
    curves_svg = "<p>No training_curves.csv.</p>"
    curves = folder / "training_curves.csv"
    if curves.is_file():
        with open(curves, newline="") as f:
            recs = list(csv.DictReader(f))
        cols = [c for c in (recs[0] if recs else {}) if c.startswith("loss")]
        if cols:
            steps = [float(r["step"]) for r in recs]
            curves_svg = svg_lines({c: (steps, [float(r[c]) for r in recs]) for c in cols}, "step", "loss",
                                   logy=True)
        probes = flip_probes(recs)
        if probes:
            curves_svg += "\n" + svg_lines({"neural (probe)": tuple(zip(*probes))}, "training seconds", "HDR FLIP")
    latents, latent_bytes = [], 0
    files = [(f"{j}", tex) for j, tex in enumerate(neural.usd_info["latent_textures"])]
    if tiles:  # the <UDIM> pattern: every trained tile's file
        files = [(f"{j}_{t}", tex.replace("<UDIM>", str(t))) for j, tex in files for t in tiles]
    for key, tex in files:
        j = int(key.split("_")[0])
        chain = read_mip_chain(tex)
        latent_bytes += sum(int(np.prod(lv.shape)) * 2 for lv in chain)
        save_png(out / f"{p}latents_{key}.png", _normalised(chain[0][..., :3]), linear=False)
        latents.append(f'<figure style="display:inline-block"><img src="{p}latents_{key}.png" '
                       f'alt="latents {key}"><figcaption>{html.escape(Path(tex).name)}: channels '
                       f"{4 * j}-{4 * j + 2}, {chain[0].shape[1]}x{chain[0].shape[0]}, "
                       f"{len(chain)} levels</figcaption></figure>")
    weight_bytes = weights.stat().st_size
    e = html.escape
    numbers = {"material": prim, "flip": flip, "cost": cost, "latent_bytes": latent_bytes,
               "weight_bytes": weight_bytes, "analytic_fit_seconds": round(fit_seconds, 2),
               "analytic_final_loss": analytic.final_loss, "udim_tiles": tiles}
    cost_rows = "".join(_cost_row(r) for r in cost["rows"])
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
<h3>Error versus cost</h3>
<p class="note">{e(cost["how"])}</p>
<table><tr><th class="l">model</th><th>mean HDR FLIP</th><th>evals/s ({e(cost["harness"])})</th><th class="l">note</th></tr>
{cost_rows}</table>
<div class="plots">{svg_scatter(points, f"evaluations per second ({cost['harness']})", "mean HDR FLIP")}</div>
<h3>Polar plots</h3>
<p class="note">Plane of incidence, wi 45 degrees from the normal (coming from the left); radius log1p(x/0.01),
normalised; at each chosen texel (<code>--texel U,V</code>).</p>
{''.join(polar)}
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


def flip_probes(records: list[dict]) -> list[tuple[float, float]]:
    """(training seconds, HDR FLIP) of the ``training_curves.csv`` rows that carry a ``flip_probe``
    (:class:`~mtlx2neural.render.flip_probe.FlipProbe`), in order."""
    out = []
    for r in records:
        try:
            value = float(r.get("flip_probe") or "nan")
        except ValueError:
            continue
        if math.isfinite(value):
            out.append((float(r["seconds"]), value))
    return out


def default_report_dir(layer) -> Path:
    layer = Path(layer).resolve()
    return layer.parent / f"{layer.stem}_report"


def write_report(layer, out=None, analytic_iterations: int = 300, res: int = 96, spp: int = 8,
                 seed: int = 0, materials: list[str] | None = None, texels_at=None, train_sizes: bool = False) -> dict:
    """Write ``out/index.html`` (default ``<layer stem>_report/`` beside the layer) and its PNGs.

    ``materials`` restricts the report to these prim paths; ``texels_at`` lists the (u, v)
    texture coordinates of the polar plots (default the centre, (0.5, 0.5)); ``train_sizes``
    trains the decoder sizes whose FLIP the conversion did not measure (:func:`cost_table`). Returns ``{"html": Path,
    "materials": [per-material numbers]}``. Raises :class:`~mtlx2neural.errors.InputError` for a
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
            body=f"<ul>{toc}</ul>" + "".join(bodies))
        (tmp / "index.html").write_text(page)
        (tmp / "report.json").write_text(json.dumps(numbers, indent=2))
    return {"html": out / "index.html", "materials": numbers}
