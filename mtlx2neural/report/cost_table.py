"""The report's error-versus-cost table: mean HDR FLIP against evaluations per second per model.

Rows are the MaterialX reference, the analytic baseline and every decoder size (:data:`.plan.DECODERS`).
Costs are timed on the generated shaders (:mod:`.shader_cost`, slangpy's CPU device) where it is
available, else on the torch models (:func:`evals_per_second`). A decoder size the conversion did
not train either takes its FLIP from the conversion's error-budget run, or is trained for the report
(:func:`size_trainer`, ``report --train-sizes``), or is left unknown.
"""

from __future__ import annotations

import html
import math
import tempfile
import time

import numpy as np
import torch

from mtlx2neural.contract import Material, ShadingPoint
from mtlx2neural.errors import InputError
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.pipeline.plan import DECODERS
from mtlx2neural.render.renderer import compare
from mtlx2neural.render.udim_view import compare_tiles, model_tiles
from mtlx2neural.report.shader_cost import shader_available, shader_rates
from mtlx2neural.scene import find_material
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.directions import half_difference_pairs
from mtlx2neural.train.trainer import Trainer


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


def cost_row(r: dict) -> str:
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


def size_trainer(record: MaterialRecord, reference, stack, texels: tuple[int, int], tiles, res: int, spp: int):
    """A function decoder -> (model, mean HDR FLIP) that trains that decoder size with the conversion's
    settings (``record.config``) on ``stack`` and measures it at the report's views (per tile for a
    UDIM material): :func:`cost_table`'s ``train_sizes``."""

    def train_size(decoder: str):
        cfg = TrainConfig(**{**record.config, "decoder": decoder, "compile": False})
        with tempfile.TemporaryDirectory(prefix="m2n_report_") as tmp_dir:
            model = Trainer(reference, stack, cfg, tmp_dir).run(progress=False)
        if tiles:
            errs = compare_tiles(reference, {"neural": model}, texels, tiles, res=res, spp=spp)["neural"]
        else:
            errs = compare(reference, model, texels, res=res, spp=spp)
        return model, float(np.mean([e["flip"] for e in errs]))

    return train_size
