# ruff: noqa  (an archived measurement script, run as written from /work/main)
"""Controlled experiment: mean radiance over the sphere, GlslRenderer node vs torch, env lighting."""
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, "/work/main")
from mtlx2neural.usd_schema import register; register()
from mtlx2neural.codegen.glsl_render import (
    environment_for_torch,
    irradiance_map,
    read_exr,
    render_plan,
    write_exr,
)
from mtlx2neural.codegen.materialx_node import write_materialx_node
from mtlx2neural.export.load import load_neural
from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.renderer import render_scene

torch.set_num_threads(1)
W = Path("/tmp/s23I/w"); W.mkdir(parents=True, exist_ok=True)
mat = sys.argv[1] if len(sys.argv) > 1 else "Plastic"
layer = "/tmp/s23d/spheres_out.usda"
variants = sys.argv[2].split(",") if len(sys.argv) > 2 else ["base"]
envs = sys.argv[3].split(",") if len(sys.argv) > 3 else ["const", "sky"]
nsamp = int(sys.argv[4]) if len(sys.argv) > 4 else 256
size = int(sys.argv[5]) if len(sys.argv) > 5 else 128
model = load_neural(layer, f"/World/Looks/{mat}")
texels = tuple(model.latents.levels[0].shape[1:])
src = Path(f"/tmp/s23d/spheres_out/World.Looks.{mat}/neural")
base = W / f"{mat}_base"
if base.exists(): shutil.rmtree(base)
mtlx = write_materialx_node(src, f"/World/Looks/{mat}", base, env_samples=0)
glsl = next(base.glob("*.glsl"))
EDITS = {
 "base": [],
 "lod0": [("float envLod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);", "float envLod = 0.0;")],
 "nocap": [("float maxEnvLod = max(float($envRadianceMips - 6), 0.0);", "float maxEnvLod = 1e9;")],
 "lv4": [("float maxEnvLod = max(float($envRadianceMips - 6), 0.0);", "float maxEnvLod = max(float($envRadianceMips - 5), 0.0);")],
 "seed2": [("_random(block, 2u)", "_random(block, 12u)"), ("_random(block, 3u)", "_random(block, 13u)")],
 "seed3": [("_random(block, 2u)", "_random(block, 22u)"), ("_random(block, 3u)", "_random(block, 23u)")],
 "lod0n": [("float envLod = min(mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n), maxEnvLod);", "float envLod = 0.0;")],
 "lodm1": [("float envLod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);", "float envLod = max(mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n) - 1.0, 0.0);")],
 "lodm2": [("float envLod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);", "float envLod = max(mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n) - 2.0, 0.0);")],
 "cap4": [("float envLod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);", "float envLod = min(mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n), max(float($envRadianceMips - 5), 0.0));")],
 "cap3": [("float envLod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);", "float envLod = min(mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n), max(float($envRadianceMips - 4), 0.0));")],
 "fixed": [("vec2 shift = vec2(", "vec2 shift = 0.0*vec2(")],
}
def variant(v):
    d = W / f"{mat}_{v}"
    if v != "base":
        if d.exists(): shutil.rmtree(d)
        shutil.copytree(base, d)
        t = glsl.read_text()
        for v1 in v.split("+"):
            for a, b in EDITS[v1]:
                assert a in t, a
                t = t.replace(a, b)
        (d / glsl.name).write_text(t)
    return d / mtlx.name
sky = environment_for_torch(EnvironmentMap.sky(128, 256).image.numpy())
ENV = {"const": np.full((64, 128, 3), 1.0, np.float32) * np.array([1.0, 0.8, 0.6], np.float32), "sky": sky}
for e, img in ENV.items():
    write_exr(W / f"{e}.exr", img); write_exr(W / f"{e}_irr.exr", irradiance_map(img))
jobs, keys = [], []
for e in envs:
    for v in variants:
        jobs.append({"mtlx": str(variant(v)), "out": str(W / f"gl_{mat}_{v}_{e}_{nsamp}.exr"), "size": size, "frames": 0,
                     "environment": str(W / f"{e}.exr"), "irradiance": str(W / f"{e}_irr.exr"), "environment_samples": nsamp})
        keys.append((e, v))
t0 = time.time(); render_plan({"renders": jobs}, timeout=3000); print("gl s", time.time() - t0, flush=True)
res = size // 2
for e in envs:
    cache = W / f"torch_{mat}_{e}_{res}.npy"
    if cache.exists(): ours = np.load(cache)
    else:
        t0 = time.time()
        ours = render_scene(model, Sphere(), Camera(0.0, 0.0, 3.0, 45.0), [EnvironmentMap(environment_for_torch(ENV[e]))],
                            res=res, spp=int(sys.argv[6]) if len(sys.argv) > 6 else 256, texels=texels, seed=2, sampler=model, footprint=1.0)
        np.save(cache, ours); print("torch s", time.time() - t0, flush=True)
    for (e2, v), job in zip(keys, jobs):
        if e2 != e: continue
        g = read_exr(job["out"]); h = g.shape[0] // res
        g = g.reshape(res, h, res, h, 4).mean((1, 3))
        m = g[..., 3] > 0.999
        a, b = g[..., :3][m].mean(0), ours[m].mean(0)
        from mtlx2neural.render.renderer import image_errors
        fl = image_errors(ours, g[..., :3])["flip"]
        print(f"{mat} {e} {v} n={nsamp}: gl {np.round(a,4)} torch {np.round(b,4)} ratio {np.round(a/b,4)} flip {fl:.4f}", flush=True)
