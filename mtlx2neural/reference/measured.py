"""A measured, isotropic BRDF read from a MERL table, as a :class:`~mtlx2neural.contract.Material`.

``m2n.load_measured("gold.binary")`` returns a :class:`MeasuredMaterial`. It is uniform (no texture):
``at`` is checked and ignored. Conventions are the contract's: local frame with z the normal, ``wi``
to the viewer, ``wo`` to the light, ``eval`` = f(wi, wo) * max(0, wo.z) in linear RGB (the table's
channels are taken as linear Rec.709 RGB, as the data set's renderers do), 0 at or below the horizon.

**eval** looks the table up at the pair's half/difference angles
(:func:`mtlx2neural.formats.merl.half_difference_angles`):

- ``interpolation="linear"`` (the default) interpolates trilinearly between the table's nodes in index
  space (square-root theta_h, linear theta_d, phi_d periodic over the fold), so the BRDF is continuous,
  which a network fits more easily; at a node it returns the node's value exactly;
- ``interpolation="nearest"`` is the format's reference reader: the index truncated and clamped.

Unmeasured entries (stored negative) read as 0, as do the indices past the table's last node (clamped).

**sample / pdf** mix two strategies, chosen by the third random number (or by rescaling the first):

- a cosine-weighted hemisphere, with probability ``diffuse_share`` (the table's share of energy in its
  floor, clamped to [0.1, 0.9]);
- a *tabulated half-vector* distribution: one piecewise-constant density per theta_h ring of the table
  (the ring between two nodes, uniform in solid angle within it), proportional to the table's mean
  luminance over theta_d and phi_d at that theta_h times cos theta_h. A sampled half vector ``h``
  reflects ``wi`` into ``wo = 2 (wi.h) h - wi``, with density p_h(h) / (4 wi.h) per steradian.

A half vector facing away from ``wi`` (``wi.h <= 0``) gives a failed sample (``wo`` straight down, weight
0, pdf 0), as does a ``wo`` at or below the horizon, so ``sample``'s pdf always equals :meth:`pdf` of the
direction it returns (``pdf`` integrates to 1 minus the probability of failure).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mtlx2neural.contract import (
    above_horizon,
    estimate_albedo,
    normalize_directions,
    prepare_direction,
    prepare_directions,
    prepare_point,
    prepare_values,
    zero_below_horizon,
)
from mtlx2neural.formats.merl import (
    MerlTable,
    continuous_index,
    half_difference_angles,
    read_merl,
)
from mtlx2neural.reference.vec import INV_PI, cosine_sample

INTERPOLATIONS = ("linear", "nearest")
DIFFUSE_SHARE_RANGE = (0.1, 0.9)
FLOOR_FROM_DEGREES = 45.0
"""theta_h from which the table's mean luminance counts as its diffuse floor (for ``diffuse_share``)."""


class MeasuredMaterial:
    """eval / sample / pdf / albedo / describe of a MERL table on any torch device (module docstring)."""

    def __init__(self, table: MerlTable, device="cpu", dtype: torch.dtype = torch.float32,
                 interpolation: str = "linear", name: str | None = None):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, not {interpolation!r}")
        self.device, self.dtype, self.interpolation = torch.device(device), dtype, interpolation
        self.source = table.source
        self.name = name or (table.source.rsplit("/", 1)[-1] if table.source else "measured")
        self.dims = table.dims
        self.missing = int(table.missing.sum())
        # [n_theta_h * n_theta_d * n_phi_d, 3]: one gather per corner returns RGB
        rgb = np.clip(table.rgb, 0.0, None).reshape(3, -1).T
        self._table = torch.as_tensor(np.ascontiguousarray(rgb), dtype=dtype, device=self.device)
        self._build_half_vector_density(table)

    # -- the sampler's tables ------------------------------------------------------------
    def _build_half_vector_density(self, table: MerlTable) -> None:
        n_h = self.dims[0]
        lum = np.clip(table.rgb, 0.0, None)
        lum = 0.2126 * lum[0] + 0.7152 * lum[1] + 0.0722 * lum[2]  # [n_h, n_d, n_p]
        ring_mean = lum.mean(axis=(1, 2))  # mean luminance per theta_h node
        edges = (np.arange(n_h + 1, dtype=np.float64) / n_h) ** 2 * (0.5 * math.pi)
        cos_edges = np.cos(edges)
        solid = 2.0 * math.pi * (cos_edges[:-1] - cos_edges[1:])  # each ring's solid angle
        centre_cos = 0.5 * (cos_edges[:-1] + cos_edges[1:])
        mass = ring_mean * centre_cos * solid
        total = float(mass.sum())  # the energy the half-vector rings carry
        if not total > 0:  # an all-black table: uniform over the rings' solid angle
            mass = solid.copy()
        prob = mass / mass.sum()
        floor = float(lum[edges[:-1] >= math.radians(FLOOR_FROM_DEGREES)].mean()) if n_h > 1 else 0.0
        diffuse = math.pi * floor
        share = diffuse / total if total > 0 else 0.5
        self.diffuse_share = float(min(max(share, DIFFUSE_SHARE_RANGE[0]), DIFFUSE_SHARE_RANGE[1]))
        kw = dict(dtype=self.dtype, device=self.device)
        self._ring_prob = torch.as_tensor(prob, **kw)
        self._ring_cdf = torch.as_tensor(np.cumsum(prob), **kw)
        self._ring_density = torch.as_tensor(prob / solid, **kw)  # per steradian of h
        self._cos_edges = torch.as_tensor(cos_edges, **kw)

    # -- lookups ---------------------------------------------------------------------------
    def _brdf(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """f(wi, wo) [N,3] in 1/sr (no cosine) from the table, for unit directions above the horizon."""
        th, td, pd = half_difference_angles(wi, wo)
        ih, idd, ip = continuous_index(th, td, pd, self.dims)
        n_h, n_d, n_p = self.dims
        if self.interpolation == "nearest":
            i = ih.floor().long().clamp(0, n_h - 1)
            j = idd.floor().long().clamp(0, n_d - 1)
            k = ip.floor().long().clamp(0, n_p - 1)
            return self._table[(i * n_d + j) * n_p + k]
        ih = ih.clamp(0.0, n_h - 1.0)
        idd = idd.clamp(0.0, n_d - 1.0)
        i0, j0, k0 = ih.floor(), idd.floor(), ip.floor()
        fi, fj, fk = (ih - i0)[:, None], (idd - j0)[:, None], (ip - k0)[:, None]
        i0, j0, k0 = i0.long(), j0.long(), k0.long() % n_p
        i1, j1, k1 = (i0 + 1).clamp(max=n_h - 1), (j0 + 1).clamp(max=n_d - 1), (k0 + 1) % n_p  # phi_d wraps
        out = torch.zeros(wi.shape[0], 3, dtype=self.dtype, device=self.device)
        for i, wi_ in ((i0, 1 - fi), (i1, fi)):
            for j, wj in ((j0, 1 - fj), (j1, fj)):
                for k, wk in ((k0, 1 - fk), (k1, fk)):
                    out = out + self._table[(i * n_d + j) * n_p + k] * (wi_ * wj * wk)
        return out

    def _half_density(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Solid-angle density [N] of ``wo`` under the tabulated half-vector strategy."""
        h = wi + wo
        h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-30)
        theta_h = torch.atan2(torch.hypot(h[:, 0], h[:, 1]), h[:, 2])
        ring = (torch.sqrt((theta_h / (0.5 * math.pi)).clamp_min(0.0)) * self.dims[0]).floor().long()
        ring = ring.clamp(0, self.dims[0] - 1)
        ph = self._ring_density[ring]
        wo_h = (wo * h).sum(-1)
        ok = (h[:, 2] > 0) & (wo_h > 0)
        return torch.where(ok, ph / (4.0 * wo_h.clamp_min(1e-30)), torch.zeros_like(ph))

    def _pdf(self, wi, wo):
        c = self.diffuse_share
        return c * wo[:, 2].clamp_min(0.0) * INV_PI + (1.0 - c) * self._half_density(wi, wo)

    # -- the contract ------------------------------------------------------------------------
    def eval(self, wi, wo, at=None) -> torch.Tensor:
        """f(wi, wo) * max(0, wo.z): [N,3] linear RGB, the cosine included; 0 at or below the horizon.
        ``at`` is checked and ignored (a measured BRDF has no texture)."""
        wi, wo = prepare_directions(wi, wo, self.dtype, self.device)
        prepare_point(at, self.dtype, self.device)
        f = self._brdf(wi, wo) * wo[:, 2:3].clamp_min(0.0)
        return torch.where(above_horizon(wi, wo), f, torch.zeros_like(f))

    def pdf(self, wi, wo, at=None) -> torch.Tensor:
        """Solid-angle density [N] (1/sr, no cosine) of :meth:`sample` at ``wo``; 0 at or below the horizon."""
        wi, wo = prepare_directions(wi, wo, self.dtype, self.device)
        prepare_point(at, self.dtype, self.device)
        return zero_below_horizon(self._pdf(wi, wo), wi, wo)

    def sample(self, wi, u, at=None):
        """``(wo [N,3], weight = eval/pdf [N,3], pdf [N])`` from uniform ``u`` [N,2] or [N,3] (the third
        number picks the strategy; with two, the first is rescaled after picking). Failed samples
        (module docstring) give weight 0 and pdf 0."""
        wi = prepare_direction("wi", wi, self.dtype, self.device)
        n = wi.shape[0]
        u = prepare_values("u", u, self.dtype, self.device, rows=n, width=(2, 3))
        prepare_point(at, self.dtype, self.device)
        c = self.diffuse_share
        u0, u1 = u[:, 0], u[:, 1]
        pick = u[:, 2] if u.shape[1] > 2 else u0
        diffuse = pick < c
        if u.shape[1] == 2:  # reuse the first number within the chosen strategy's interval
            u0 = torch.where(diffuse, u0 / c, (u0 - c) / (1.0 - c)).clamp(0.0, 1.0 - 1e-7)
        wo_d = cosine_sample(torch.stack([u0, u1], -1))
        # half vector: a ring by its probability, then uniform in solid angle within it
        ring = torch.searchsorted(self._ring_cdf, u0[:, None].clamp(max=1 - 1e-7)).clamp(max=self.dims[0] - 1)[:, 0]
        lo = torch.where(ring > 0, self._ring_cdf[(ring - 1).clamp_min(0)], torch.zeros_like(u0))
        t = ((u0 - lo) / self._ring_prob[ring].clamp_min(1e-30)).clamp(0.0, 1.0)
        cos_t = self._cos_edges[ring] + t * (self._cos_edges[ring + 1] - self._cos_edges[ring])
        sin_t = (1.0 - cos_t * cos_t).clamp_min(0.0).sqrt()
        phi = 2.0 * math.pi * u1
        h = torch.stack([sin_t * phi.cos(), sin_t * phi.sin(), cos_t], -1)
        wi_h = (wi * h).sum(-1, keepdim=True)
        wo_h = 2.0 * wi_h * h - wi
        wo_h = torch.where(wi_h > 0, wo_h, torch.tensor([0.0, 0.0, -1.0], dtype=self.dtype, device=self.device))
        wo = normalize_directions(torch.where(diffuse[:, None], wo_d, wo_h))
        pdf = zero_below_horizon(self._pdf(wi, wo), wi, wo)
        f = self._brdf(wi, wo) * wo[:, 2:3].clamp_min(0.0)
        ok = (pdf > 0)[:, None] & above_horizon(wi, wo)
        weight = torch.where(ok, f / pdf.clamp_min(1e-30)[:, None], torch.zeros_like(f))
        return wo, weight, pdf

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0) -> torch.Tensor:
        """Directional albedo [N,3] (the integral of eval over wo, cosine included), by
        :func:`~mtlx2neural.contract.estimate_albedo`; 0 at or below the horizon."""
        wi = prepare_direction("wi", wi, self.dtype, self.device)
        return estimate_albedo(self, wi, at, samples, seed)

    def describe(self) -> dict:
        """What the table is: its file, dimensions, unmeasured entries, lookup and sampling settings."""
        return {"kind": "measured (MERL)", "source": self.source, "dims": list(self.dims),
                "unmeasured_entries": self.missing, "interpolation": self.interpolation,
                "diffuse_share": round(self.diffuse_share, 4)}


def load_measured(path, device="cpu", interpolation: str = "linear") -> MeasuredMaterial:
    """Read a MERL ``.binary`` file (:func:`mtlx2neural.formats.merl.read_merl`; ``InputError`` naming it
    when it is unreadable or malformed) as a :class:`MeasuredMaterial` on ``device``."""
    return MeasuredMaterial(read_merl(path), device=device, interpolation=interpolation)
