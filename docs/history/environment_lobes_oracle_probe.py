"""Probe (issue 33, 2026-12-06): which lobes and which reflectance split the prefiltered environment path needs.

Shades a converted material's sphere as ``render.prefiltered`` does (64², camera (0, 0, 3), 45 degrees, the sky), with
each pixel's lobe reflectance computed by Monte Carlo from the **reference** (an oracle for the environment head), and
prints HDR FLIP against the reference rendered at 2048 spp (cached in ``--work``). Modes:

- ``current``: the model's own head and lobes;
- ``resp``: the sampler's two lobes, reflectance split by their responsibilities;
- ``ls``: the same lobes, reflectance by least squares onto their shapes;
- ``trueA_B_..``: GGX lobes of alpha A, B... about the mirror direction plus Lambert, non-negative least squares;
- ``coatplusA``: a GGX lobe of alpha A plus the sampler's two, least squares;
- ``coatrespA_W``: a sharp lobe of alpha A plus the sampler's two, responsibilities with the sharp lobe at weight W;
- ``resp3``: the model's three lobes (sharp, specular, diffuse), responsibilities as ``train.environment_fit`` splits;
- ``ls3``: the same lobes, non-negative least squares onto their shapes; ``ls3e``: the same with the sum held to the
  albedo; ``hyb3``: the sharp lobe by least squares, the rest by the sampler's two-lobe responsibilities; ``excess3``:
  the sharp lobe takes f's excess over the sampler's two-lobe fit; ``ring3R``: responsibilities, the sharp lobe's
  kept as far as f at the sample exceeds f R sharp alphas out (what ``train.environment_fit`` ships with R = 8)
  (2026-12-07; each also prints the brightest pixel against the reference's).

    python docs/history/environment_lobes_oracle_probe.py LAYER.usda MATERIAL MODE [SAMPLES] [--work DIR]

(SPP, NS, DIFF in the environment: passes per pixel, lattice directions, a lattice diffuse lookup.)
Results: docs/history/environment-lighting-2026-12-06.md and environment-lighting-2026-12-07.md.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from mtlx2neural.export.load import load_neural
from mtlx2neural.graph import compile_material
from mtlx2neural.model import proxy
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.prefiltered import PrefilteredEnvironment
from mtlx2neural.render.renderer import image_errors, render_scene
from mtlx2neural.scene.loader import find_material

args = [a for a in sys.argv[1:] if not a.startswith("--work")]
WORK = Path(next((a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--work=")), "/tmp/env"))
layer, mat, mode = args[0], args[1], args[2]
M = int(args[3]) if len(args) > 3 else 128
summary = json.loads(next(Path(layer).with_suffix("").glob(f"*{mat}/summary.json")).read_text())
model = load_neural(layer, summary["material"])
src = find_material(summary["source"], summary["material"])
ref = ReferenceMaterial(compile_material(src.document, src.material))
g = torch.Generator().manual_seed(0)


def nnls(A, rhs, free):
    """Non-negative least squares by active sets: solve A c = rhs per row ([n, K, K], [n, K, 3]) over the lobes still
    ``free`` ([n, K] bool), dropping those that come out negative."""
    K = A.shape[-1]
    for _ in range(K):
        Af = A * (free[:, :, None] & free[:, None, :]) + torch.diag_embed((~free).float())
        sol = torch.linalg.solve(Af, rhs * free[:, :, None])
        neg = (sol < 0).any(-1) & free
        if not neg.any():
            break
        free = free & ~neg
    return sol.clamp_min(0) * free[:, :, None]


class Oracle:
    def __init__(self, m): self.m = m
    def __getattr__(self, k): return getattr(self.m, k)
    def environment_lobes(self, wi, at=None):
        wi, p, c = self.m.environment_lobes(wi, at)
        if mode == "current": return wi, p, c
        n = wi.shape[0]
        rep = lambda t: t.repeat_interleave(M, 0)
        P = proxy.ProxyParams(*(rep(v) for v in (p.alpha, p.rho, p.slope_spec, p.slope_diff, p.w_spec)))
        W = rep(wi)
        u = torch.rand(n * M, 3, generator=g)
        wo_ref, _, _ = ref.sample(W, u[:, :2])
        wo_own = proxy.sample(W, P, u[:, :2])
        use = (u[:, 2] < 0.5) & torch.isfinite(wo_ref).all(-1)
        use_ref = (u[:, 2] < 1 / 3) & torch.isfinite(wo_ref).all(-1)
        wo = torch.where(use[:, None], torch.nan_to_num(wo_ref), wo_own)
        wo = wo / wo.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        ps = proxy.pdf_specular(W, wo, P)
        pd = proxy.pdf_diffuse(wo, P.slope_diff)
        q = 0.5 * (P.w_spec[:, 0] * ps + (1 - P.w_spec[:, 0]) * pd + ref.pdf(W, wo))
        f = ref.eval(W, wo)
        ok = (wo[:, 2] > 0) & (q > 0)
        wgt = torch.where(ok, 1 / q.clamp_min(1e-30), torch.zeros_like(q)) / M
        if mode in ("resp3", "ls3", "hyb3", "ls3e", "excess3") or mode.startswith("ring3"):
            # the model's three lobes (sharp, specular, diffuse), directions from the reference, the sampler and
            # the sharp lobe (a third each), as train.environment_fit draws them
            S = proxy.sharp_params(P)
            wo_sh = proxy.sample_specular(W, S, u[:, :2])
            wo = torch.where(use_ref[:, None], torch.nan_to_num(wo_ref), torch.where((u[:, 2] < 2 / 3)[:, None], wo_own, wo_sh))
            wo = wo / wo.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            ps = proxy.pdf_specular(W, wo, P); pd = proxy.pdf_diffuse(wo, P.slope_diff); pc = proxy.pdf_specular(W, wo, S)
            pm = P.w_spec[:, 0] * ps + (1 - P.w_spec[:, 0]) * pd
            q = (pm + ref.pdf(W, wo) + pc) / 3
            f = ref.eval(W, wo)
            ok = (wo[:, 2] > 0) & (q > 0)
            wgt = torch.where(ok, 1 / q.clamp_min(1e-30), torch.zeros_like(q)) / M
            y = f * wgt[:, None]
            if mode == "excess3":
                # the sharp lobe takes f's excess over the sampler's two lobes as their two-lobe
                # responsibilities would fit them (c2_spec p_spec + c2_diff p_diff), the rest split by those
                r2 = (P.w_spec[:, 0] * ps / pm.clamp_min(1e-30))[:, None]
                c2s = (y * r2).view(n, M, 3).sum(1); c2d = (y * (1 - r2)).view(n, M, 3).sum(1)
                mir = torch.cat([wo[:, :2], -wo[:, 2:]], -1)
                gsm = (c2s.repeat_interleave(M, 0) * (ps + proxy.pdf_specular(W, mir, P))[:, None]
                     + c2d.repeat_interleave(M, 0) * pd[:, None])
                rs = ((f - gsm) / f.clamp_min(1e-30)).clamp(0.0, 1.0) * (pc > 0)[:, None]
                cc = (y * rs).view(n, M, 3).sum(1)
                cs = (y * (1 - rs) * r2).view(n, M, 3).sum(1); cd = (y * (1 - rs) * (1 - r2)).view(n, M, 3).sum(1)
                return wi, p, torch.stack([cc, cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
            if mode.startswith("ring3"):
                # responsibilities in the three-lobe mixture, the sharp lobe's share scaled by how much of f at the
                # sample is its own peak: 1 - f(ring) / f(sample), the ring RING sharp alphas out in slope space
                RING = float(mode[5:] or 4)
                Wt = proxy.SHARP_WEIGHT
                p3 = Wt * pc + (1 - Wt) * pm
                r_c = (Wt * pc / p3.clamp_min(1e-30))[:, None]
                r_s = ((1 - Wt) * P.w_spec[:, 0] * ps / p3.clamp_min(1e-30))[:, None]
                h = W + wo; h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-12)
                hz = h[:, 2:].clamp_min(1e-6)
                d = torch.cat([-h[:, :1] / hz, -h[:, 1:2] / hz], -1) - S.slope_spec
                dn = d.norm(dim=-1, keepdim=True)
                dirn = torch.where(dn > 1e-9, d / dn.clamp_min(1e-12), torch.tensor([[1.0, 0.0]]))
                hr = proxy.slope_axis(S.slope_spec + RING * proxy.SHARP_ALPHA * dirn)
                ring = 2 * (W * hr).sum(-1, keepdim=True) * hr - W
                fr = torch.where((ring[:, 2:] > 0), ref.eval(W, ring), torch.zeros_like(f))
                rho = (1 - fr / f.clamp_min(1e-30)).clamp(0, 1)
                cc = (y * r_c * rho).view(n, M, 3).sum(1); cs = (y * (r_s + r_c * (1 - rho))).view(n, M, 3).sum(1)
                cd = (y * (1 - r_c - r_s)).view(n, M, 3).sum(1)
                return wi, p, torch.stack([cc, cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
            if mode in ("resp3", "hyb3"):
                Wt = proxy.SHARP_WEIGHT
                p3 = Wt * pc + (1 - Wt) * pm
                r_c = (Wt * pc / p3.clamp_min(1e-30))[:, None]
                r_s = ((1 - Wt) * P.w_spec[:, 0] * ps / p3.clamp_min(1e-30))[:, None]
                if mode == "resp3":
                    cc = (y * r_c).view(n, M, 3).sum(1); cs = (y * r_s).view(n, M, 3).sum(1); cd = (y * (1 - r_c - r_s)).view(n, M, 3).sum(1)
                    return wi, p, torch.stack([cc, cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
            mir = torch.cat([wo[:, :2], -wo[:, 2:]], -1)
            bases = [pc + proxy.pdf_specular(W, mir, S), ps + proxy.pdf_specular(W, mir, P), pd]
            K = 3
            B = torch.stack(bases, -1) * ok[:, None]
            wv = wgt.view(n, M); Bv = B.view(n, M, K)
            A = torch.einsum("nmi,nmj,nm->nij", Bv, Bv, wv) + 1e-9 * torch.eye(K)
            rhs = torch.einsum("nmi,nmc,nm->nic", Bv, f.view(n, M, 3), wv)
            free = torch.ones(n, K, dtype=torch.bool)
            if mode == "ls3e":  # least squares with the lobes' sum held to the albedo estimate (KKT), c >= 0
                alb = y.view(n, M, 3).sum(1)  # [n, 3]
                for _ in range(K):
                    Af = A * (free[:, :, None] & free[:, None, :]) + torch.diag_embed((~free).float())
                    one = free.float()
                    Kk = torch.zeros(n, K + 1, K + 1)
                    Kk[:, :K, :K] = Af; Kk[:, :K, K] = one; Kk[:, K, :K] = one
                    r = torch.cat([rhs * free[:, :, None], alb[:, None]], 1)
                    sol = torch.linalg.solve(Kk, r)[:, :K]
                    neg = (sol < 0).any(-1) & free
                    if not neg.any(): break
                    free = free & ~neg
                sol = sol.clamp_min(0) * free[:, :, None]
                return wi, p, sol * (wi[:, None, 2:3] > 0)
            sol = nnls(A, rhs, free)
            if mode == "ls3":
                return wi, p, sol * (wi[:, None, 2:3] > 0)
            # hyb3: the sharp lobe's reflectance by least squares, the rest split by the sampler's two-lobe
            # responsibilities, the sharp lobe's share taken from the specular lobe's
            r2 = (P.w_spec[:, 0] * ps / pm.clamp_min(1e-30))[:, None]
            cs = (y * r2).view(n, M, 3).sum(1); cd = (y * (1 - r2)).view(n, M, 3).sum(1)
            cc = torch.minimum(sol[:, 0], cs)
            return wi, p, torch.stack([cc, cs - cc, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
        if mode == "resp":
            pm = P.w_spec[:, 0] * ps + (1 - P.w_spec[:, 0]) * pd
            r = (P.w_spec[:, 0] * ps / pm.clamp_min(1e-30))[:, None]
            y = f * wgt[:, None]
            cs = (y * r).view(n, M, 3).sum(1); cd = (y * (1 - r)).view(n, M, 3).sum(1)
            return wi, p, torch.stack([torch.zeros_like(cs), cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
        if mode.startswith("coatresp"):
            a, w2 = (float(x) for x in mode[8:].split("_"))
            Q = proxy.ProxyParams(torch.full((n*M, 2), a), torch.zeros(n*M, 1), torch.zeros(n*M, 2), torch.zeros(n*M, 2), torch.ones(n*M, 1))
            pc = proxy.pdf_specular(W, wo, Q)
            pm = P.w_spec[:, 0] * ps + (1 - P.w_spec[:, 0]) * pd
            p3 = w2 * pc + (1 - w2) * pm
            # draw: keep the same draws (q); responsibilities under p3
            r_c = (w2 * pc / p3.clamp_min(1e-30))[:, None]
            r_s = ((1 - w2) * P.w_spec[:, 0] * ps / p3.clamp_min(1e-30))[:, None]
            y = f * wgt[:, None]
            cc = (y * r_c).view(n, M, 3).sum(1); cs = (y * r_s).view(n, M, 3).sum(1); cd = (y * (1 - r_c - r_s)).view(n, M, 3).sum(1)
            self.alphas = [a]
            return wi, p, torch.stack([cc, cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)
        if mode.startswith("coatplus"):
            a = float(mode[8:])
            Q = proxy.ProxyParams(torch.full((n*M, 2), a), torch.zeros(n*M, 1), torch.zeros(n*M, 2), torch.zeros(n*M, 2), torch.ones(n*M, 1))
            mir = torch.cat([wo[:, :2], -wo[:, 2:]], -1)
            bases = [proxy.pdf_specular(W, wo, Q) + proxy.pdf_specular(W, mir, Q), ps + proxy.pdf_specular(W, mir, P), pd]
            self.alphas = [a]
        elif mode.startswith("true"):
            alphas = [float(a) for a in mode[4:].split("_")]
            bases = []
            for a in alphas:
                Q = proxy.ProxyParams(torch.full((n*M, 2), a), torch.zeros(n*M, 1), torch.zeros(n*M, 2), torch.zeros(n*M, 2), torch.ones(n*M, 1))
                bases.append(proxy.pdf_specular(W, wo, Q) + proxy.pdf_specular(W, torch.cat([wo[:, :2], -wo[:, 2:]], -1), Q))
            bases.append(wo[:, 2].clamp_min(0) / math.pi)
        if mode.startswith("true") or mode.startswith("coatplus"):
            K = len(bases)
            B = torch.stack(bases, -1) * ok[:, None]
            wv = wgt.view(n, M); Bv = B.view(n, M, K)
            A = torch.einsum("nmi,nmj,nm->nij", Bv, Bv, wv) + 1e-9 * torch.eye(K)
            rhs = torch.einsum("nmi,nmc,nm->nic", Bv, f.view(n, M, 3), wv)
            free = torch.ones(n, K, dtype=torch.bool)
            sol = nnls(A, rhs, free)
            self.sol = sol
            if mode.startswith("true"): self.alphas = alphas
            return wi, p, sol
        # least squares onto the two lobe shapes (spec folded above the horizon)
        mir = torch.cat([wo[:, :2], -wo[:, 2:]], -1)
        bs = ps + proxy.pdf_specular(W, mir, P)
        bd = pd
        B = torch.stack([bs, bd], -1) * ok[:, None]
        wv = wgt.view(n, M)
        Bv = B.view(n, M, 2)
        A = torch.einsum("nmi,nmj,nm->nij", Bv, Bv, wv) + 1e-9 * torch.eye(2)
        rhs = torch.einsum("nmi,nmc,nm->nic", Bv, f.view(n, M, 3), wv)
        sol = torch.linalg.solve(A, rhs)  # [n,2,3]
        # non-negative: where one is negative, refit the other alone
        s_only = rhs[:, 0] / A[:, 0, 0, None]; d_only = rhs[:, 1] / A[:, 1, 1, None]
        neg_s = sol[:, 0] < 0; neg_d = sol[:, 1] < 0
        cs = torch.where(neg_s, 0.0, torch.where(neg_d, s_only, sol[:, 0]))
        cd = torch.where(neg_d, 0.0, torch.where(neg_s, d_only, sol[:, 1]))
        return wi, p, torch.stack([torch.zeros_like(cs), cs, cd], 1).clamp_min(0) * (wi[:, None, 2:3] > 0)

import mtlx2neural.render.prefiltered as PF
from mtlx2neural.render.prefiltered import lobe_means

if mode.startswith("coatplus") or mode.startswith("coatresp"):
    def prf(material, pyramid, basis, wi, at=None, samples=16):
        with torch.no_grad():
            wi, p, c = material.environment_lobes(wi, at)
            n = wi.shape[0]
            a = material.alphas[0]
            Q = proxy.ProxyParams(torch.full((n, 2), a), torch.zeros(n, 1), torch.zeros(n, 2), torch.zeros(n, 2), torch.ones(n, 1))
            e_coat = lobe_means(pyramid, basis, wi, Q, samples)[:, 1]  # the lattice over the coat lobe
            e = lobe_means(pyramid, basis, wi, p, samples)  # [sharp, specular, diffuse]
            E = torch.stack([e_coat, e[:, 1], e[:, 2]], 1)
        return (c * E).sum(1) * (wi[:, 2:3] > 0)
    PF.prefiltered_radiance = prf
elif mode.startswith("true"):
    def prf(material, pyramid, basis, wi, at=None, samples=16):
        with torch.no_grad():
            wi, p, c = material.environment_lobes(wi, at)
            n = wi.shape[0]
            es = []
            for a in material.alphas:
                Q = proxy.ProxyParams(torch.full((n, 2), a), torch.zeros(n, 1), torch.zeros(n, 2), torch.zeros(n, 2), torch.ones(n, 1))
                e = lobe_means(pyramid, basis, wi, Q, samples)
                es.append(e[:, 1])
            import os
            if os.environ.get("DIFF"):
                S = int(os.environ["DIFF"])
                from mtlx2neural.render.prefiltered import _lobe_mean, lattice
                u = lattice(S).repeat(n, 1)
                wd = proxy.sample_diffuse(torch.zeros(n * S, 2), u)
                es.append(_lobe_mean(pyramid, basis, wd.view(n, S, 3), (wd[:, 2].clamp_min(0) / math.pi).view(n, S), S))
            else:
                es.append(e[:, 2])
            E = torch.stack(es, 1)
        return (c * E).sum(1) * (wi[:, 2:3] > 0)
    PF.prefiltered_radiance = prf
sky = [EnvironmentMap(EnvironmentMap.sky(128, 256).image.numpy())]
texels = tuple(model.latents.levels[0].shape[1:])
with torch.no_grad():
    img = render_scene(Oracle(model), Sphere(), Camera(0.0, 0.0, 3.0, 45.0), [PrefilteredEnvironment(sky[0], int(__import__("os").environ.get("NS", "16")))], res=64, spp=int(__import__("os").environ.get("SPP", "4")), texels=texels, seed=2, footprint=1.0)
cache = WORK / mat / "conv2048.npy"
if cache.exists():
    big = np.load(cache)
else:  # 8 x 256 spp of the reference, light and BSDF samples (MIS)
    cache.parent.mkdir(parents=True, exist_ok=True)
    big = np.mean([render_scene(ref, Sphere(), Camera(0.0, 0.0, 3.0, 45.0), sky, res=64, spp=256, texels=texels,
                                seed=100 + s, sampler=ref, footprint=1.0) for s in range(8)], 0)
    np.save(cache, big)
np.save(WORK / mat / f"o_{mode}.npy", img)
LUM = np.array([0.2126, 0.7152, 0.0722], np.float32)
print(mat, mode, "vs conv2048", round(image_errors(big, img)["flip"], 4), "peak ratio", round(float((img @ LUM).max() / (big @ LUM).max()), 3), img.mean((0, 1)).round(4), big.mean((0, 1)).round(4), flush=True)
