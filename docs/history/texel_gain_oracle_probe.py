"""Oracle probe: scale the model's BRDF per texel (each MIP level's texel its own RGB gain = the reference's
footprint albedo / the model's, over four view angles), then render the summary views. If the sky view's error is
the model's per-texel energy, the figure falls.

    python docs/history/texel_gain_oracle_probe.py LAYER.usda MATERIAL [MAX_LEVEL]   (2026-12-08, issue 31)
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from mtlx2neural.export.load import load_neural
from mtlx2neural.graph import compile_material
from mtlx2neural.model.latent import LatentPyramid
from mtlx2neural.pipeline.plan import latent_resolution
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render import summary_views as sv
from mtlx2neural.scene.loader import find_material
from mtlx2neural.textures.footprint_albedo import (
    model_level_albedo,
    reference_footprint_albedo,
    view_directions,
)
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset

layer, mat = sys.argv[1], sys.argv[2]
max_level = int(sys.argv[3]) if len(sys.argv) > 3 else 99
summary = json.loads(next(Path(layer).with_suffix("").glob(f"*{mat}/summary.json")).read_text())
model = load_neural(layer, summary["material"])
src = find_material(summary["source"], summary["material"])
compiled = compile_material(src.document, src.material)
ref = ReferenceMaterial(compiled)
stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, preset("fast")))
res = tuple(stack.resolution)
params_at = stack.native_params_at()
levels = model.latents.levels
H, W = levels[0].shape[-2:]
gp = LatentPyramid(H, W, channels=3)
g = torch.Generator().manual_seed(5)
VIEWS = (0.0, 30.0, 60.0, 80.0)
t0 = time.time()
for k, lv in enumerate(levels):
    h, w = lv.shape[-2:]
    if k > max_level:
        gp.levels[k].data.fill_(1.0)
        continue
    v, u = torch.meshgrid(1.0 - (torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w, indexing="ij")  # row 0 at v = 1 (grid_lookup)
    uv = torch.stack([u, v], -1).reshape(-1, 2)  # texel centres, row-major (u along width)
    wi, _ = view_directions(uv.shape[0], VIEWS, g)
    uvr = uv.repeat_interleave(len(VIEWS), 0)
    refs, mods = [], []
    for s in range(0, uvr.shape[0], 16384):
        sl = slice(s, s + 16384)
        refs.append(reference_footprint_albedo(ref, wi[sl], uvr[sl], k, res, points=2, samples=32, seed=1,
                                               generator=g, params_at=params_at))
        with torch.no_grad():
            mods.append(model_level_albedo(model, ref, wi[sl], uvr[sl], k, samples=(128 if k == 0 else 256), seed=2, params_at=params_at))
    r = torch.cat(refs).view(-1, len(VIEWS), 3).sum(1)
    m = torch.cat(mods).view(-1, len(VIEWS), 3).sum(1)
    gain = (r / m.clamp_min(1e-6)).clamp(0.25, 4.0)
    gp.levels[k].data = gain.T.reshape(3, h, w).to(lv.dtype)
    lum = gain.mean(1)
    print(f"level {k} {h}x{w}: gain mean {lum.mean():.3f} std {lum.std():.3f} [{lum.min():.2f}, {lum.max():.2f}]"
          f" {time.time() - t0:.0f}s", flush=True)

# the layout: the gain pyramid read back at level 0's texel centres equals what was stored
h0, w0 = levels[0].shape[-2:]
vv, uu = torch.meshgrid(1.0 - (torch.arange(h0) + 0.5) / h0, (torch.arange(w0) + 0.5) / w0, indexing="ij")
uv0 = torch.stack([uu, vv], -1).reshape(-1, 2)
with torch.no_grad():
    back = gp(uv0, torch.zeros(uv0.shape[0]), torch.zeros(uv0.shape[0]))
print("layout check", float((back - gp.levels[0].detach().reshape(3, -1).T).abs().max()))
orig_eval, orig_sample = model.eval, model.sample


def gain_at(n, at):
    saved = model.latents
    model.latents = gp
    try:
        return model._latent_at(n, at)
    finally:
        model.latents = saved


def eval_g(wi, wo, at=None):
    f = orig_eval(wi, wo, at)
    return f * gain_at(f.shape[0], at).to(f.dtype)


def sample_g(wi, u, at=None):
    wo, weight, pdf = orig_sample(wi, u, at)
    return wo, weight * gain_at(wo.shape[0], at).to(weight.dtype), pdf


texels = res
base = sv.summary_views(ref, {"n": model}, texels)["n"]
model.eval, model.sample = eval_g, sample_g
gained = sv.summary_views(ref, {"n": model}, texels)["n"]
print("views before", [round(float(r["flip"]), 4) for r in base], "mean", round(float(np.mean([r["flip"] for r in base])), 4))
print("views gained", [round(float(r["flip"]), 4) for r in gained], "mean", round(float(np.mean([r["flip"] for r in gained])), 4))
