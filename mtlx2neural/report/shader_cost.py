"""Shader evaluations per second of every model of the trade, in one harness (slangpy's CPU device).

The cost axis of the speed-for-accuracy trade (``mtlx2neural report``,
``benchmarks/bench_tradeoff.py``), measured on the code a renderer runs, not on torch:

- **reference**: MaterialX's own generated Slang for the material
  (:func:`mtlx2neural.oracle.runner.mtlx_slang_eval`). Its kernel shades every query
  twice (lit and unlit), so its rate is doubled; it samples its textures at one uv.
- **neural** (one entry per decoder): the generated FP32 module
  (:func:`mtlx2neural.codegen.generate_slang`) fetching its latent pyramid (stochastic level,
  bilinear) and evaluating in one thread (``CpuMaterial.fetch_eval``). The cost does not depend
  on the weights' values, so decoder sizes that were not trained can be timed with seeded weights.
- **analytic**: ``codegen/slang/AnalyticMaterial.slang`` with the same fetch
  (``CpuAnalytic.fetch_eval``).

Each rate is the best of ``repeats`` dispatches of ``n`` random (uv, lod, wi, wo) queries,
buffer uploads included for all. On a CPU the FP16 and CoopVec variants are emulated, so only
FP32 is timed here; the figures rank models, they do not predict GPU times.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from mtlx2neural.baseline.shader_harness import CpuAnalytic, decoded_levels
from mtlx2neural.codegen import as_spec, generate_slang
from mtlx2neural.codegen.cpu import CpuMaterial, slangpy_available
from mtlx2neural.oracle.runner import OracleError, mtlx_slang_eval, oracle_available
from mtlx2neural.train.directions import half_difference_pairs


def best_time(fn, repeats: int = 3) -> float:
    """Shortest wall time in seconds of ``repeats`` calls of ``fn`` after one warm-up call."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return max(best, 1e-9)


def random_queries(n: int, levels: int, seed: int = 0) -> list[np.ndarray]:
    """(wi, wo, uv, lod, u) float32: directions uniform in half/difference angles (local frame),
    uv uniform in [0, 1)², lod uniform in [0, levels - 1], u uniform (level choice)."""

    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = torch.rand(n, 2, generator=g)
    lod = torch.rand(n, generator=g) * max(levels - 1, 0)
    u = torch.rand(n, generator=g)
    return [t.numpy().astype(np.float32) for t in (wi, wo, uv, lod, u)]


def shader_available() -> tuple[bool, str]:
    """(ok, reason) for timing shaders: slangpy with a CPU device."""

    return slangpy_available()


def shader_rates(neural: dict, analytic=None, mtlx_source=None, n: int = 16384, repeats: int = 3) -> dict:
    """Evaluations per second: ``{label: rate or None}`` for each of ``neural`` (``{label:
    NeuralMaterial}``), ``"analytic"`` (an :class:`~mtlx2neural.baseline.analytic_model.AnalyticMaterial`)
    and ``"reference"`` (``mtlx_source``, a :class:`mtlx2neural.scene.MaterialSource`). None where
    the harness or MaterialX's oracle is unavailable; ``"reference_note"`` says why."""

    rates: dict = {"reference": None, "analytic": None, **dict.fromkeys(neural)}
    ok, why = shader_available()
    if not ok:
        rates["reference_note"] = why
        return rates
    for label, model in neural.items():
        levels = [lv.detach().float().numpy() for lv in model.latents.levels]
        wi, wo, uv, lod, u = random_queries(n, len(levels))
        ident = "Cost" + "".join(c if c.isalnum() else "_" for c in str(label))
        cm = CpuMaterial(generate_slang(model, ident), ident, as_spec(model), "FP32")
        pyr = cm.pyramid(levels)
        rates[label] = n / best_time(lambda cm=cm, pyr=pyr, q=(uv, lod, u, wi, wo): cm.fetch_eval(pyr, *q), repeats)
    if analytic is not None:
        am = CpuAnalytic()
        levels = decoded_levels(analytic)
        wi, wo, uv, lod, u = random_queries(n, len(levels))
        pyr = am.pyramid(levels)
        rates["analytic"] = n / best_time(lambda: am.fetch_eval(pyr, uv, lod, u, wi, wo), repeats)
    if mtlx_source is not None:

        ok, why = oracle_available()
        wi, wo = random_queries(n, 1)[:2]
        try:
            if not ok:
                raise OracleError(why)
            if getattr(mtlx_source, "measured", False):
                raise OracleError("a measured table (MERL) has no MaterialX shader to time")
            # the oracle kernel shades each query twice (lit and unlit): one BSDF costs half
            rates["reference"] = 2 * n / best_time(
                lambda: mtlx_slang_eval(mtlx_source.document, mtlx_source.material, wi, wo), repeats)
        except OracleError as exc:
            rates["reference_note"] = f"MaterialX oracle unavailable: {exc}"
    return rates
