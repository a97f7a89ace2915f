"""How good is an importance sampler? Variance of the one-sample estimator f*cos/pdf, and its cost.

For a fixed incoming direction ``wi`` the estimator ``W = L(eval(wi, wo)) / pdf(wo)``
with ``wo ~ pdf`` has mean equal to the directional albedo (luminance of
f*cos integrated over the hemisphere, the cosine included in ``eval``). A
perfect sampler (pdf proportional to f*cos) has zero variance. We report the
*relative* variance var(W) / E[W]^2 (scale-free: a dark and a bright material
compare) averaged over a set of ``wi``, and the time to unit relative variance:
seconds per sample (sample + pdf + eval) times the relative variance, i.e. the
time a renderer spends to bring the relative variance of a pixel's estimate to 1
(lower is better; it trades a sampler's cost against its quality).

Directions are in the local shading frame (z = normal).
"""

from __future__ import annotations

import math
import time
from typing import Callable

import torch

LUMINANCE = (0.2126, 0.7152, 0.0722)  # Rec.709 weights for the scalar estimator


def cosine_sample(wi: torch.Tensor, u: torch.Tensor):
    """Cosine-weighted hemisphere sampling: (wo [N,3], pdf [N] per steradian = cos / pi)."""
    phi = 2.0 * math.pi * u[:, 0]
    r = u[:, 1].sqrt()
    z = (1.0 - u[:, 1]).clamp_min(0).sqrt()
    wo = torch.stack([r * phi.cos(), r * phi.sin(), z], -1)
    return wo, z / math.pi


def elevation_directions(degrees=(0.0, 30.0, 60.0, 80.0), azimuths: int = 4) -> torch.Tensor:
    """A fixed set of ``wi``: each elevation from the normal (degrees) at ``azimuths`` azimuths."""
    out = []
    for d in degrees:
        t = math.radians(d)
        for k in range(azimuths):
            p = 2.0 * math.pi * (k + 0.5) / azimuths
            out.append([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    return torch.tensor(out)


def estimator_statistics(eval_fn: Callable, sample_fn: Callable, wis: torch.Tensor, n: int = 4096,
                         seed: int = 0) -> dict:
    """Relative variance and cost of ``eval_fn(wi, wo) / pdf`` with ``wo, pdf = sample_fn(wi, u)``.

    ``eval_fn`` returns f*cos [N,3]; ``sample_fn`` returns (wo [N,3], pdf [N]). Zero-pdf samples
    count as zero-valued (a sampler that misses part of the lobe is biased, and that shows as a
    lower mean). Returns ``{"mean": [len(wis)], "rel_var": float (mean over wi),
    "seconds_per_sample": float, "time_to_unit_variance": float (seconds)}``.
    """
    g = torch.Generator().manual_seed(seed)
    lum = torch.tensor(LUMINANCE)
    means, rel = [], []
    elapsed = 0.0
    for wi in wis:
        wi_n = wi.expand(n, 3).contiguous()
        u = torch.rand(n, 2, generator=g)
        with torch.no_grad():
            t = time.perf_counter()
            wo, pdf = sample_fn(wi_n, u)
            f = eval_fn(wi_n, wo)
            elapsed += time.perf_counter() - t
        ok = (pdf > 0) & torch.isfinite(pdf)
        w = torch.where(ok, (f * lum).sum(-1) / pdf.clamp_min(1e-20), torch.zeros_like(pdf))
        m = float(w.mean())
        means.append(m)
        rel.append(float(w.var()) / max(m * m, 1e-20))
    per_sample = elapsed / (n * len(wis))
    rel_var = sum(rel) / len(rel)
    return {"mean": means, "rel_var": rel_var, "seconds_per_sample": per_sample,
            "time_to_unit_variance": per_sample * rel_var}


def neural_sample_fn(model, uv=None):
    """``sample_fn`` for a :class:`~mtlx2neural.model.neural_material.NeuralMaterial`'s learned
    sampler at one ``uv`` [1,2] (None: the uniform material's single texel)."""
    return lambda wi, u: model.sample_direction(wi, u, None if uv is None else uv.expand(wi.shape[0], 2))
