"""The neural material in MaterialX's own GLSL renderer, against the original material.

Run:  python benchmarks/bench_viewer.py [--layers OUT.usda,...] [--materials CarPaint,Plastic,GlazedCeramic]
                                       [--decoders Plastic=2x32]
      (from the repository root; needs xvfb-run or a DISPLAY, and MaterialX's GLSL render module)

Without ``--layers`` the samples are copied into ``--work`` (default: a folder under the system
temporary folder, kept for reuse) and converted there with ``mtlx2neural convert --preset fast``
(the two spheres of ``samples/layered_spheres.usda`` and the GlazedCeramic of the textured sample,
which ``samples/make_textured_sample.py`` writes when the repository has no copy; ``--decoders`` names
another decoder for some of them); a rerun reuses the unchanged conversions. For each material:

(a) its ``NeuralMaterial_<name>.mtlx`` node (written here from the exported ``neural/`` folder by
    ``codegen.materialx_node.write_materialx_node``, as the export writes ``neural/materialx/``, but
    with ``env_samples`` 0: the renderer's FIS count, the one (c) uses) rendered by MaterialX's ``GlslRenderer``
    (``codegen.glsl_render``: Xvfb + Mesa llvmpipe) on a unit sphere, camera at (0, 0, 3), 45
    degrees vertical field of view, under one ``directional_light`` (a MaterialX light rig; light
    from world direction (0.4, 0.7, 0.6), y up, intensity 3);
(b) the same view by the project's torch renderer of the exported neural model
    (``render.renderer.render_scene``, 16 jittered samples per pixel);
(c) the ORIGINAL material (the source document's surfacematerial, converted from the USD
    network as the tool reads it) by the same ``GlslRenderer``, same view and light;
(a) and (c) again under MaterialX's environment lighting (``--compare-samples`` directions per
    pixel, no direct light): the project's procedural sky (``EnvironmentMap.sky``, turned so MaterialX
    shows it as the torch renderer does) with its irradiance map (``glsl_render.irradiance_map``). The
    node (a) as exported shades it prefiltered when the model has an environment head
    (``env_prefiltered``); it is also rendered with the environment sampled by its learned sampler
    (``env_prefiltered`` false), and both again with their random streams offset (``seed`` 1): the
    noise is the HDR FLIP between the two renders of one node. (c) is also rendered converged
    (``--converged-samples`` FIS directions): FLIP (a)-(c converged) is the node's error without the
    original's own, which FLIP (c)-(c converged) shows.

Comparison frames: GlslRenderer at 256² (``--compare-size``; ``--gl-supersample 4``: 512²), compared
box-filtered to 128² with torch's 128² (16 samples per pixel); mean HDR FLIP over the whole frame (background included, as the tool's own summary
FLIP; the JSON also has the mean over the sphere's pixels, and a diagnosis against the project's
reference BSDF of the original, :func:`diagnose`). Frame time: (a) and (c) at 512² in the same
GlslRenderer process, light rig plus the sky at 16 directions (MaterialXView's default count), the
median of ``--frames`` draws after a warm-up draw, in ``--rounds`` alternating rounds; the ratio
(a) / (c) is reported for both environment modes (llvmpipe is a CPU rasteriser: the ratio matters,
not the time). The diagnosis also compares the torch renderer's prefiltered mode
(``render.prefiltered``) with the reference converged (256 samples per pixel).

Prints a Markdown table and writes the figures as JSON (``--json``) with the machine (host, CPU,
cores, GL renderer string). ``--screenshot PNG`` writes the original (left) and the neural node
(right) side by side as MaterialX rendered them, for ``--screenshot-material`` under
``--screenshot-lighting``: ``viewer`` (default: the timing frames, light rig plus the sky at 16
directions, MaterialXView's defaults, 512² box-filtered to 256²), ``directional`` or ``environment``
(the comparison frames).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples"
sys.path.insert(0, str(ROOT))

# The package is importable from a source checkout without an install (run from the root).
import MaterialX as mx  # noqa: E402
import torch  # noqa: E402

from mtlx2neural.codegen.glsl_render import (  # noqa: E402
    directional_light_rig,
    environment_for_torch,
    gl_unavailable,
    irradiance_map,
    read_exr,
    render_plan,
    write_exr,
)
from mtlx2neural.codegen.materialx_node import write_materialx_node  # noqa: E402
from mtlx2neural.export.load import load_neural  # noqa: E402
from mtlx2neural.graph import compile_material  # noqa: E402
from mtlx2neural.pipeline.layout import material_folder  # noqa: E402
from mtlx2neural.reference import ReferenceMaterial  # noqa: E402
from mtlx2neural.render.geometry import Camera, Sphere  # noqa: E402
from mtlx2neural.render.lighting import DirectionalLight, EnvironmentMap  # noqa: E402
from mtlx2neural.render.prefiltered import PrefilteredEnvironment  # noqa: E402
from mtlx2neural.render.renderer import image_errors, render_scene, save_png  # noqa: E402
from mtlx2neural.scene.loader import find_material  # noqa: E402
from mtlx2neural.usd_schema import register as register_usd_schema  # noqa: E402

LIGHT = (0.4, 0.7, 0.6)  # towards the light, world space (y up), as tests/codegen/test_materialx_node.py
INTENSITY = 3.0
SIZE = 512  # GlslRenderer frames for the frame time
COMPARE_SIZE = 256  # GlslRenderer frames for the comparisons; compared box-filtered to half
COMPARE_SAMPLES = 32  # environment directions per pixel for the comparison frames
CONVERGED_SAMPLES = 1024  # the original's FIS directions for its converged environment frame
TIMING_SAMPLES = 16  # MaterialXView's default FIS sample count
DEFAULT_MATERIALS = ("CarPaint", "Plastic", "GlazedCeramic")


# ------------------------------------------------------------------------------ inputs


def convert_samples(work: Path, materials, decoders: dict | None = None) -> list[Path]:
    """Copy the samples into ``work/samples`` and convert them there (``fast`` preset, with the decoder
    ``decoders`` names for a material, {name: "2x32"}); returns the neural layers. Nothing is written into
    the repository."""
    src = work / "samples"
    src.mkdir(parents=True, exist_ok=True)
    layers = []
    spheres = [m for m in materials if m != "GlazedCeramic"]
    if spheres:
        shutil.copy(SAMPLES / "layered_spheres.usda", src / "layered_spheres.usda")
        layers.append(_convert(src / "layered_spheres.usda", work / "spheres_neural", spheres, decoders))
    if "GlazedCeramic" in materials:
        textured = src / "textured"
        if (SAMPLES / "textured" / "ceramic_and_metal.usda").is_file():
            if not (textured / "ceramic_and_metal.usda").is_file():
                shutil.copytree(SAMPLES / "textured", textured, dirs_exist_ok=True)
        elif not (textured / "ceramic_and_metal.usda").is_file():
            subprocess.run([sys.executable, str(SAMPLES / "make_textured_sample.py"), str(textured)], check=True)
        layers.append(_convert(textured / "ceramic_and_metal.usda", work / "textured_neural", ["GlazedCeramic"],
                               decoders))
    return layers


def _convert(asset: Path, out: Path, materials, decoders: dict | None = None) -> Path:
    for name in materials:  # --material takes one name; the tool keeps a layer's other materials
        cmd = [sys.executable, "-m", "mtlx2neural.cli", "convert", str(asset), "--preset", "fast", "--quiet",
               "-o", str(out), "--material", name]
        if (decoders or {}).get(name):
            cmd += ["--decoder", decoders[name]]
        print(f"# {' '.join(cmd[1:])}", file=sys.stderr, flush=True)
        subprocess.run(cmd, check=True, stdout=sys.stderr)
    return out.with_suffix(".usda")


def find_conversions(layers, materials) -> dict:
    """{material: {"layer", "folder" (its OUT/<material> folder), "summary"}} for each requested
    material name (prim name, prim path or MaterialX name) found in the layers' output folders."""
    found = {}
    for layer in layers:
        out = Path(layer).with_suffix("")
        for summary_file in sorted(out.glob("*/summary.json")):
            summary = json.loads(summary_file.read_text())
            for name in materials:
                if name in (summary["material"], summary["material"].rsplit("/", 1)[-1], summary.get("mtlx_material")):
                    assert summary_file.parent.name == material_folder(summary["material"])
                    found[name] = {"layer": Path(layer), "folder": summary_file.parent, "summary": summary}
    missing = [m for m in materials if m not in found]
    if missing:
        raise SystemExit(f"no conversion of {', '.join(missing)} in {', '.join(map(str, layers))}")
    return {m: found[m] for m in materials}


def sky_for_materialx(height: int = 128, width: int = 256) -> np.ndarray:
    """The project's procedural sky (EnvironmentMap.sky) as the lat-long map MaterialX must be given
    to light the sphere as the torch renderer does with the sky (MaterialX turns the map 180 degrees
    about y; :func:`environment_for_torch` undoes that, and it is its own inverse for even widths)."""
    return environment_for_torch(EnvironmentMap.sky(height, width).image.numpy())


# ------------------------------------------------------------------------------ the benchmark


def prepare(name: str, conv: dict, work: Path) -> dict:
    """Write material ``name``'s neural node and its original document into ``work/<name>``."""
    folder = work / "viewer" / name
    folder.mkdir(parents=True, exist_ok=True)
    summary = conv["summary"]
    # env_samples 0: the renderer's FIS count, the one standard_surface uses, for both (a) and (c).
    # The node as exported (prefiltered environment when the model has an environment head), the same node
    # sampling the environment with its learned sampler, and both again with their random streams offset
    # (seed 1): two renders that differ only in random numbers.
    exported = conv["folder"] / "neural"
    nodes = {}
    for mode, prefiltered in (("neural", None), ("neural_sampled", False)):
        for seed in (0, 1):
            key = mode if seed == 0 else f"{mode}_seed1"
            nodes[key] = write_materialx_node(exported, summary["material"], folder / key, env_samples=0, seed=seed,
                                              env_prefiltered=prefiltered)
    src = find_material(summary["source"], summary["material"])
    original = folder / "original.mtlx"
    mx.writeToXmlFile(src.document, str(original))
    return {"folder": folder, **nodes, "original": original, "original_material": src.material, "source": src}


def downsample(img: np.ndarray, k: int = 2) -> np.ndarray:
    """k x k box average (a 256² GlslRenderer frame as a 4-samples-per-pixel 128² image)."""
    h, w, c = img.shape
    return img.reshape(h // k, k, w // k, k, c).mean((1, 3))


LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # linear Rec. 709


def peak_ratio(test: np.ndarray, ref: np.ndarray) -> float:
    """The brightest pixel's luminance of ``test`` over ``ref``'s ([H, W, 3] linear each): a reflection's
    peak that is lost (< 1) or one the original does not have (> 1)."""
    return float((test @ LUMINANCE).max() / max(float((ref @ LUMINANCE).max()), 1e-12))


def sphere_flip(ref: np.ndarray, test: np.ndarray, covered: np.ndarray) -> float:
    """Mean HDR FLIP over the sphere's pixels only (``covered``, [H, W] bool); the frame mean of
    :func:`image_errors` also counts the background, where both images are black."""
    from mtlx2neural.render.flip import (
        hdr_flip,  # Local: as render.renderer.image_errors, only where FLIP is computed
    )

    values, _, _ = hdr_flip(ref, test, apply_magma=False)
    values = np.asarray(values).reshape(covered.shape + (-1,))[..., 0]
    return float(values[covered].mean())


def diagnose(d: dict, model, texels, b: np.ndarray, gl: dict, size: int, supersample: int = 2) -> dict:
    """Where FLIP (a)-(c) comes from: the project's reference BSDF of the original material (the
    one the model was trained on) rendered by the torch renderer, against (c) MaterialX's GLSL of
    the original (their difference is MaterialX's GLSL code and its environment method, not the
    neural model) and against the torch renders of the neural model (the model's own error in this
    view). Directional at ``size`` / 2 (16 spp), environment at ``size`` / 4 (64 spp, light and BSDF
    samples by MIS; each material samples by its own sampler), GlslRenderer frames (``size`` / 2 x
    ``supersample``) box-filtered to match."""
    src = d["source"]
    ref = ReferenceMaterial(compile_material(src.document, src.material))
    cam, sphere = Camera(0.0, 0.0, 3.0, 45.0), Sphere()
    sun = [DirectionalLight(LIGHT, INTENSITY)]
    ref_dir = render_scene(ref, sphere, cam, sun, res=size // 2, spp=16, texels=texels, seed=1, footprint=0.5)
    sky = [EnvironmentMap(EnvironmentMap.sky(128, 256).image.numpy())]
    env = {}
    for label, m in (("reference", ref), ("neural", model)):
        env[label] = render_scene(m, sphere, cam, sky, res=size // 4, spp=64, texels=texels, seed=2, sampler=m,
                                  footprint=1.0)
        save_png(d["folder"] / f"torch_{label}_environment.png", env[label])
    # The torch renderer's prefiltered mode (render.prefiltered, no noise) against the reference converged
    # (256 samples per pixel, light and BSDF samples by MIS).
    converged = render_scene(ref, sphere, cam, sky, res=size // 4, spp=256, texels=texels, seed=3, sampler=ref,
                             footprint=1.0)
    env["prefiltered"] = render_scene(model, sphere, cam, [PrefilteredEnvironment(sky[0])], res=size // 4, spp=16,
                                      texels=texels, seed=2, footprint=1.0)
    save_png(d["folder"] / "torch_prefiltered_environment.png", env["prefiltered"])
    save_png(d["folder"] / "torch_reference_directional.png", ref_dir)
    c_dir = downsample(gl[("directional", "original")], supersample)[..., :3]
    a_env = downsample(gl[("environment", "neural")], 2 * supersample)[..., :3]
    c_env = downsample(gl[("environment", "original")], 2 * supersample)[..., :3]

    mask = downsample(gl[("environment", "original")], 2 * supersample)[..., 3] > 0.999  # sphere pixels here

    def f(x, y):
        return round(image_errors(x, y)["flip"], 4)

    return {"directional": {"reference_vs_c": f(ref_dir, c_dir), "reference_vs_b": f(ref_dir, b)},
            "torch_prefiltered_vs_converged_reference": f(converged, env["prefiltered"]),
            "torch_sampled_vs_converged_reference": f(converged, env["neural"]),
            "environment_quarter": {"reference_vs_c": f(env["reference"], c_env), "reference_vs_a": f(env["reference"], a_env),
                                "reference_vs_torch_neural": f(env["reference"], env["neural"]),
                                "a_vs_c": f(c_env, a_env),
                                "mean_rgb_sphere": {k: np.round(v[mask].mean(0), 4).tolist() for k, v in
                                                    (("torch_reference", env["reference"]),
                                                     ("torch_neural", env["neural"]), ("a", a_env), ("c", c_env))}}}


def run(args) -> dict:
    materials = [m for m in args.materials.split(",") if m]
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    items = [item for item in args.decoders.split(",") if item]
    if any("=" not in item for item in items):
        raise SystemExit(f"--decoders {args.decoders!r}: give MATERIAL=SIZE,... (e.g. Plastic=2x32)")
    decoders = dict(item.split("=", 1) for item in items)
    layers = [Path(p) for p in args.layers.split(",")] if args.layers else convert_samples(work, materials, decoders)
    convs = find_conversions(layers, materials)
    lighting = work / "viewer"
    lighting.mkdir(parents=True, exist_ok=True)
    rig = lighting / "rig.mtlx"
    rig.write_text(directional_light_rig([-c for c in LIGHT], INTENSITY))
    sky = sky_for_materialx()
    write_exr(lighting / "sky.exr", sky)
    write_exr(lighting / "sky_irradiance.exr", irradiance_map(sky))
    directional = {"lights": str(rig), "environment": None, "irradiance": None}
    environment = {"lights": None, "environment": str(lighting / "sky.exr"),
                   "irradiance": str(lighting / "sky_irradiance.exr"), "environment_samples": args.compare_samples}
    timing = {"lights": str(rig), "environment": str(lighting / "sky.exr"),
              "irradiance": str(lighting / "sky_irradiance.exr"), "environment_samples": TIMING_SAMPLES}

    docs = {m: prepare(m, convs[m], work) for m in materials}
    jobs, keys = [], []
    env_labels = ("neural", "neural_seed1", "neural_sampled", "neural_sampled_seed1", "original")
    for m, d in docs.items():
        for light, extra, labels in (("directional", directional, ("neural", "original")),
                                     ("environment", environment, env_labels)):
            for label in labels:
                mat = d["original_material"] if label == "original" else None
                jobs.append({**extra, "mtlx": str(d[label]), "material": mat,
                             "out": str(d["folder"] / f"gl_{light}_{label}.exr"),
                             "size": args.compare_size // 2 * args.gl_supersample,
                             "frames": 0})
                keys.append((m, light, label))
        # The original converged: its FIS at --converged-samples directions (its own error at
        # --compare-samples is then measured, not charged to the node).
        jobs.append({**environment, "environment_samples": args.converged_samples, "mtlx": str(d["original"]),
                     "material": d["original_material"], "out": str(d["folder"] / "gl_environment_original_converged.exr"),
                     "size": args.compare_size // 2 * args.gl_supersample, "frames": 0})
        keys.append((m, "environment", "original_converged"))
    for r in range(args.rounds):
        for m, d in docs.items():
            for label in ("neural", "neural_sampled", "original"):
                mat = d["original_material"] if label == "original" else None
                jobs.append({**timing, "mtlx": str(d[label]), "material": mat,
                             "out": str(d["folder"] / f"gl_timing_{label}.exr"), "size": SIZE, "frames": args.frames})
                keys.append((m, f"timing{r}", label))
    t0 = time.perf_counter()
    results = render_plan({"renders": jobs}, timeout=args.timeout)
    gl_seconds = time.perf_counter() - t0
    out = {m: {} for m in materials}
    for key, job, res in zip(keys, jobs, results["renders"]):
        m, light, label = key
        if light.startswith("timing"):
            out[m].setdefault(f"seconds_{label}", []).append(res["seconds_per_frame"])
        else:
            out[m][(light, label)] = read_exr(job["out"])

    rows = []
    torch.manual_seed(0)
    for m in materials:
        d, conv, o = docs[m], convs[m], out[m]
        model = load_neural(conv["layer"], conv["summary"]["material"])
        texels = tuple(model.latents.levels[0].shape[1:])
        # footprint 1 / supersample: the level of detail of one sample of the GlslRenderer frame.
        b = render_scene(model, Sphere(), Camera(0.0, 0.0, 3.0, 45.0), [DirectionalLight(LIGHT, INTENSITY)],
                         res=args.compare_size // 2, spp=16, texels=texels, seed=1,
                         footprint=1.0 / args.gl_supersample)
        diag = diagnose(d, model, texels, b, o, args.compare_size, args.gl_supersample)
        imgs = {k: downsample(v, args.gl_supersample) for k, v in o.items() if isinstance(k, tuple)}
        covered = imgs[("directional", "neural")][..., 3] > 0.5
        rgb = {k: v[..., :3] for k, v in imgs.items()}
        ab = image_errors(b, rgb[("directional", "neural")])  # torch as the reference, as the test
        ac_dir = image_errors(rgb[("directional", "original")], rgb[("directional", "neural")])
        ac_env = image_errors(rgb[("environment", "original")], rgb[("environment", "neural")])
        ac_env_sampled = image_errors(rgb[("environment", "original")], rgb[("environment", "neural_sampled")])
        converged = rgb[("environment", "original_converged")]
        ac_env_converged = image_errors(converged, rgb[("environment", "neural")])
        cc_env = image_errors(converged, rgb[("environment", "original")])
        # Noise: two renders of one node that differ only in their random streams (HDR FLIP between them).
        noise = {mode: image_errors(rgb[("environment", mode)], rgb[("environment", f"{mode}_seed1")])["flip"]
                 for mode in ("neural", "neural_sampled")}
        sa, sc = float(np.median(o["seconds_neural"])), float(np.median(o["seconds_original"]))
        ss = float(np.median(o["seconds_neural_sampled"]))
        for name, img in (("a_directional", rgb[("directional", "neural")]), ("b_torch_directional", b),
                          ("c_directional", rgb[("directional", "original")]),
                          ("a_environment", rgb[("environment", "neural")]),
                          ("c_environment", rgb[("environment", "original")])):
            save_png(d["folder"] / f"{name}.png", img)
        for name, e in (("flip_a_b", ab), ("flip_a_c_directional", ac_dir), ("flip_a_c_environment", ac_env)):
            save_png(d["folder"] / f"{name}.png", e["flip_map"], linear=False)
        rows.append({
            "material": conv["summary"]["material"], "decoder": conv["summary"]["decoder"],
            "steps": conv["summary"]["steps"], "summary_flip": conv["summary"]["flip_mean"],
            "flip_a_b": round(ab["flip"], 4),
            "flip_a_c_directional": round(ac_dir["flip"], 4),
            "flip_a_c_environment": round(ac_env["flip"], 4),
            "environment_mode": "prefiltered" if model.has_environment_head else "sampled",
            "flip_a_c_environment_sampled": round(ac_env_sampled["flip"], 4),
            "flip_a_c_environment_converged": round(ac_env_converged["flip"], 4),
            "flip_c_c_environment_converged": round(cc_env["flip"], 4),
            # the brightest pixel under the sky against the converged original's (compared frames, 128²)
            "peak_ratio_environment": {mode: round(peak_ratio(rgb[("environment", label)], converged), 3)
                                       for mode, label in (("prefiltered", "neural"), ("sampled", "neural_sampled"))},
            "noise_flip_environment": round(noise["neural"], 4),
            "noise_flip_environment_sampled": round(noise["neural_sampled"], 4),
            "sphere_only": {"flip_a_b": round(sphere_flip(b, rgb[("directional", "neural")], covered), 4),
                            "flip_a_c_directional": round(sphere_flip(rgb[("directional", "original")],
                                                                      rgb[("directional", "neural")], covered), 4),
                            "flip_a_c_environment": round(sphere_flip(rgb[("environment", "original")],
                                                                      rgb[("environment", "neural")], covered), 4)},
            "diagnosis": diag,
            "mean_rgb_sphere": {f"{light}_{label}": np.round(rgb[(light, label)][covered].mean(0), 4).tolist()
                                for light in ("directional", "environment") for label in ("neural", "original")},
            "seconds_per_frame_neural": o["seconds_neural"], "seconds_per_frame_original": o["seconds_original"],
            "seconds_per_frame_neural_sampled": o["seconds_neural_sampled"],
            "frame_time_ratio": round(sa / sc, 2), "frame_time_ratio_sampled": round(ss / sc, 2),
            "images": str(d["folder"]),
        })
        if args.screenshot and m == args.screenshot_material:
            light = args.screenshot_lighting
            if light == "viewer":  # the last timing frames, 512² box-filtered to 256²
                pair = [downsample(read_exr(d["folder"] / f"gl_timing_{k}.exr")) for k in ("original", "neural")]
            else:
                pair = [o[(light, k)] for k in ("original", "neural")]
            side = np.concatenate([x[..., :3] for x in pair], 1)
            Path(args.screenshot).parent.mkdir(parents=True, exist_ok=True)
            save_png(args.screenshot, side)
    return {"rows": rows, "machine": machine(results.get("renderer")), "gl_seconds": round(gl_seconds, 1),
            "settings": {"timing_size": SIZE, "compare_size": args.compare_size,
                         "compared_at": args.compare_size // 2, "gl_supersample": args.gl_supersample, "light_towards": LIGHT, "intensity": INTENSITY,
                         "environment": "EnvironmentMap.sky(128, 256), FIS", "compare_env_samples": args.compare_samples,
                         "converged_env_samples": args.converged_samples, "decoders": args.decoders,
                         "timing": f"{SIZE}² light rig + sky at {TIMING_SAMPLES} directions, median of "
                                   f"{args.frames} frames after a warm-up, {args.rounds} rounds",
                         "torch_spp": 16},
            "layers": [str(p) for p in layers]}


def machine(gl_renderer: str | None) -> dict:
    cpu = platform.processor()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"host": platform.node(), "cpu": cpu, "cores": os.cpu_count(), "gl_renderer": gl_renderer,
            "materialx": mx.getVersionString(), "torch": torch.__version__, "python": platform.python_version(),
            "date": time.strftime("%Y-%m-%d")}


def table(report: dict) -> str:
    lines = ["| material | decoder | tool's FLIP (summary.json) | FLIP (a)-(b) | FLIP (a)-(c) directional | "
             "FLIP (a)-(c) environment, prefiltered / sampled | (a)-(c converged) / (c)-(c converged) | "
             "noise, prefiltered / sampled | frame time (a) / (c), prefiltered / sampled | "
             "torch prefiltered vs converged reference |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        sa, sc = np.median(r["seconds_per_frame_neural"]), np.median(r["seconds_per_frame_original"])
        ss = np.median(r["seconds_per_frame_neural_sampled"])
        lines.append(f"| {r['material'].rsplit('/', 1)[-1]} | {r['decoder']} | {r['summary_flip']:.3f} | "
                     f"{r['flip_a_b']:.3f} | {r['flip_a_c_directional']:.3f} | {r['flip_a_c_environment']:.3f} / "
                     f"{r['flip_a_c_environment_sampled']:.3f} | {r['flip_a_c_environment_converged']:.3f} / "
                     f"{r['flip_c_c_environment_converged']:.3f} | {r['noise_flip_environment']:.3f} / "
                     f"{r['noise_flip_environment_sampled']:.3f} | **{r['frame_time_ratio']:.2f}x** / "
                     f"{r['frame_time_ratio_sampled']:.2f}x ({sa * 1000:.0f} / {ss * 1000:.0f} / {sc * 1000:.0f} ms) | "
                     f"{r['diagnosis']['torch_prefiltered_vs_converged_reference']:.3f} |")
    m = report["machine"]
    lines.append("")
    lines.append(f"Machine: {m['host']}, {m['cpu']}, {m['cores']} cores; GL: {m['gl_renderer']}; "
                 f"MaterialX {m['materialx']}; {m['date']}.")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--layers", help="comma-separated neural layers of earlier conversions (default: convert "
                                     "the samples into --work)")
    ap.add_argument("--materials", default=",".join(DEFAULT_MATERIALS))
    ap.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "mtlx2neural_bench_viewer"),
                    help="working folder (conversions, documents, EXR and PNG renders)")
    ap.add_argument("--frames", type=int, default=3, help="timed frames per round after a warm-up frame")
    ap.add_argument("--rounds", type=int, default=2, help="alternating timing rounds of (a) and (c)")
    ap.add_argument("--compare-size", type=int, default=COMPARE_SIZE,
                    help="GlslRenderer frame size of the comparisons (compared box-filtered to half)")
    ap.add_argument("--gl-supersample", type=int, default=2,
                    help="GlslRenderer samples per compared pixel along each axis: its comparison frames are "
                         "compare-size / 2 x this, box-filtered to compare-size / 2 (2: 4 per pixel; 4: 16, "
                         "as many as the torch frame's)")
    ap.add_argument("--compare-samples", type=int, default=COMPARE_SAMPLES,
                    help="environment directions per pixel in the comparison frames")
    ap.add_argument("--converged-samples", type=int, default=CONVERGED_SAMPLES,
                    help="environment directions per pixel of the converged original (c converged)")
    ap.add_argument("--decoders", default="",
                    help="MATERIAL=SIZE,...: convert these materials with this decoder (2x16, 2x32, 3x64) "
                         "instead of the fast preset's 3x64")
    ap.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "viewer.json"))
    ap.add_argument("--screenshot", help="PNG: original | neural as MaterialX rendered them")
    ap.add_argument("--screenshot-lighting", choices=("viewer", "directional", "environment"),
                    default="viewer")
    ap.add_argument("--screenshot-material", default="GlazedCeramic")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds for the GlslRenderer process")
    args = ap.parse_args(argv)
    reason = gl_unavailable()
    if reason:
        print(f"skipped: MaterialX's GLSL renderer cannot run here: {reason}", file=sys.stderr)
        return 0
    register_usd_schema()  # before any stage is opened (load_neural reads the schema's attributes)
    report = run(args)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(report, indent=1))
    print(table(report))
    print(f"\nJSON: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
