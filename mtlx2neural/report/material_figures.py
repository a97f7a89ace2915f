"""The report's figures of one material: the analytic baseline refitted and every model rendered,
polar slices, training curves and latent previews.

:mod:`.html_report` lays them out; these functions compute them and write the images. Units: every
render is linear radiance (PNG-encoded by :func:`~mtlx2neural.render.renderer.save_png`); f*cos
includes the cosine; pdfs are per steradian.
"""

from __future__ import annotations

import csv
import html
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.baseline.analytic_model import fit_analytic
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.errors import InputError
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.imaging.udim import tile_of_udim, udim_at
from mtlx2neural.render.renderer import compare_many, save_png
from mtlx2neural.render.udim_view import TileView
from mtlx2neural.report.svg_plots import svg_lines, svg_polar
from mtlx2neural.textures.parameter_stack import build_parameter_stack, uniform_stack
from mtlx2neural.train.udim import build_tiled_stack


@dataclass
class BaselineRenders:
    """The analytic baseline fitted for the report and the renders of every model.

    ``stack``: the parameter stack fitted on (a tiled stack for a UDIM material); ``analytic``: the fit
    (the first tile's for UDIM); ``analytics``: {tile: fit} for UDIM, else None; ``renders``:
    {"neural" | "analytic": [per view: reference, render, flip, flip_map (, tile)]};
    ``fit_seconds``: wall-clock seconds of the fits and renders."""

    stack: object
    analytic: object
    analytics: dict | None
    renders: dict
    fit_seconds: float


def fit_and_render(reference, neural, texels: tuple[int, int], tiles, analytic_iterations: int, res: int,
                   spp: int, seed: int) -> BaselineRenders:
    """Fit the analytic baseline (``analytic_iterations`` Adam steps; per trained tile for a UDIM
    material, each on its tile's stack) and render reference, analytic and neural at the report's views
    (each tile on the sphere for UDIM, :class:`~mtlx2neural.render.udim_view.TileView`)."""
    t0 = time.time()
    if tiles:
        stack = build_tiled_stack(reference.compiled, tiles, texels)
        analytics = {t: fit_analytic(TileView(reference, t), st, iterations=analytic_iterations, batch=2048,
                                     seed=seed) for t, st in zip(tiles, stack.stacks)}
        renders = {"neural": [], "analytic": []}
        for t in tiles:
            per = compare_many(TileView(reference, t), {"neural": TileView(neural, t), "analytic": analytics[t]},
                               texels, res=res, spp=spp)
            for k in renders:
                renders[k] += [{**r, "tile": t} for r in per[k]]
        return BaselineRenders(stack, analytics[tiles[0]], analytics, renders, time.time() - t0)
    compiled = getattr(reference, "compiled", None)  # None: a measured table, uniform
    stack = uniform_stack() if compiled is None else build_parameter_stack(compiled, resolution=texels)
    analytic = fit_analytic(reference, stack, iterations=analytic_iterations, batch=2048, seed=seed)
    analytic.surface = getattr(neural, "surface", None)  # shown with the same emission and cut-out maps
    renders = compare_many(reference, {"neural": neural, "analytic": analytic}, texels, res=res, spp=spp)
    return BaselineRenders(stack, analytic, None, renders, time.time() - t0)


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


def normalised(img: np.ndarray) -> np.ndarray:
    x = img.astype(np.float32)
    lo, hi = x.min(axis=(0, 1), keepdims=True), x.max(axis=(0, 1), keepdims=True)
    return np.where(hi > lo, (x - lo) / np.maximum(hi - lo, 1e-12), 0.5)


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


def polar_figures(reference, fitted: BaselineRenders, neural, tiles, texels_at, prim: str) -> list[str]:
    """HTML of the polar plots (f*cos and sampling pdf) at each (u, v) of ``texels_at`` (None: the
    centre, or each trained tile's centre for a UDIM material, whose (u, v) must lie in a trained tile)."""
    if texels_at is None:
        texels_at = [(tu + 0.5, tv + 0.5) for tu, tv in map(tile_of_udim, tiles)] if tiles else [(0.5, 0.5)]
    out = []
    for u, v in texels_at:
        if tiles:  # the tile holding (u, v): its analytic fit at local uv, the others at true uv
            t = udim_at(u, v)
            if t not in tiles:
                raise InputError(f"--texel {u:g},{v:g}: not in a UDIM tile {prim} was trained on ({tiles})")
            tu, tv = tile_of_udim(t)
            theta, brdf, pdf = polar_slices(TileView(reference, t), fitted.analytics[t], TileView(neural, t),
                                            uv=(u - tu, v - tv))
        else:
            theta, brdf, pdf = polar_slices(reference, fitted.analytic, neural, uv=(u, v))
        out.append(f'<p class="note">uv ({u:g}, {v:g})</p><div class="plots">'
                   f'{svg_polar({k: (theta, x) for k, x in brdf.items()}, "f*cos (luminance)")}\n'
                   f'{svg_polar({k: (theta, x) for k, x in pdf.items()}, "sampling pdf (1/sr)")}</div>')
    return out


def training_curves_svg(folder: Path) -> str:
    """SVG of every ``loss*`` column of ``folder/training_curves.csv`` against step, and of the HDR FLIP
    probes against training seconds where the conversion probed."""
    curves = folder / "training_curves.csv"
    if not curves.is_file():
        return "<p>No training_curves.csv.</p>"
    with open(curves, newline="") as f:
        recs = list(csv.DictReader(f))
    out = "<p>No training_curves.csv.</p>"
    cols = [c for c in (recs[0] if recs else {}) if c.startswith("loss")]
    if cols:
        steps = [float(r["step"]) for r in recs]
        out = svg_lines({c: (steps, [float(r[c]) for r in recs]) for c in cols}, "step", "loss", logy=True)
    probes = flip_probes(recs)
    if probes:
        out += "\n" + svg_lines({"neural (probe)": tuple(zip(*probes))}, "training seconds", "HDR FLIP")
    return out


def latent_figures(neural, tiles, out: Path, prefix: str) -> tuple[list[str], int]:
    """(HTML figures, bytes at FP16 over all MIP levels) of the latent textures: channels 0-2 of each
    file's finest level, min-max normalised, written as ``<prefix>latents_<key>.png`` into ``out``
    (every trained tile's file for a UDIM material)."""
    figures, total = [], 0
    files = [(f"{j}", tex) for j, tex in enumerate(neural.usd_info["latent_textures"])]
    if tiles:  # the <UDIM> pattern: every trained tile's file
        files = [(f"{j}_{t}", tex.replace("<UDIM>", str(t))) for j, tex in files for t in tiles]
    for key, tex in files:
        j = int(key.split("_")[0])
        chain = read_mip_chain(tex)
        total += sum(int(np.prod(lv.shape)) * 2 for lv in chain)
        save_png(out / f"{prefix}latents_{key}.png", normalised(chain[0][..., :3]), linear=False)
        figures.append(f'<figure style="display:inline-block"><img src="{prefix}latents_{key}.png" '
                       f'alt="latents {key}"><figcaption>{html.escape(Path(tex).name)}: channels '
                       f"{4 * j}-{4 * j + 2}, {chain[0].shape[1]}x{chain[0].shape[0]}, "
                       f"{len(chain)} levels</figcaption></figure>")
    return figures, total
