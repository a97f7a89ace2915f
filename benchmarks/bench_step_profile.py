"""Where one training step's time goes, its FLOPs, and the machine's FLOP rate: the time-to-quality bound.

Run:  OMP_NUM_THREADS=1 python benchmarks/bench_step_profile.py [--case GlazedCeramic] [--preset standard]
          [--threads 1,2] [--steps 8] [--warmup 3] [--set FIELD=VALUE ...] [--out FILE]

For one material (default: the textured GlazedCeramic, 256² latent grid over 1024² textures, built
as ``bench_fidelity.train_and_model`` builds it) and one preset (``standard`` = ``fast`` for 8000
steps: the same step), it

1. **times a step by part**, in both phases (encoder, then fine-tuning of the baked latents), by
   wrapping the functions :meth:`Trainer.train_step` calls (exclusive times, nested calls
   subtracted): drawing the queries; the lobe directions (the reference's sampler); the targets,
   split into the material graph at the footprint points (``ReferenceMaterial.parameters_at``) and
   the BRDF (the mollifying cone's MIS: ``sample``, ``pdf``, ``eval``); the encoder or latent
   fetch; the losses' forward (decoder, sampler); the backward; the optimiser (clip + Adam); the
   rest (Python, bookkeeping). The backward is one call: its split between the networks comes
   from the same networks timed alone (forward + backward on the step's shapes).
2. **counts the FLOPs per part** with a dispatch mode: 2MNK per matrix product (``mm``, ``addmm``,
   ``bmm``: the MLPs, exact) and one per output element of every other op (elementwise work:
   the reference BRDF, the graph, the proxy; a transcendental counts 1, so this is a lower
   bound on the arithmetic). The MLPs' FLOPs are also derived from their layer shapes.
3. **measures the FLOP rate**: ``[batch, 64] @ [64, 64]`` (the decoder's hidden layer, FP32,
   with bias: ``addmm``) and a 2048² square matmul; and an elementwise rate (``a * b + c``
   on 2^20 floats, 2 FLOPs per element, and ``exp``), at each thread count.

It prints Markdown tables: per part ms/step (each thread count), FLOPs/step, share, and the
floor of the step's time if every FLOP ran at the measured square-matmul rate (or at the
decoder-shape matmul rate for the MLPs and the elementwise rate for the rest). Wall-clock
figures: run on an otherwise idle machine, or say what else ran.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import platform
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import CASES, TEXTURED
from bench_tradeoff import config_overrides

import mtlx2neural.train.targets as targets_mod
import mtlx2neural.train.trainer as trainer_mod
from mtlx2neural.graph import compile_material
from mtlx2neural.model.mlp import parse_hidden
from mtlx2neural.pipeline.plan import latent_resolution
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.scene import find_material
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset

MATMULS = {"aten.mm.default", "aten.addmm.default", "aten.bmm.default"}
NO_WORK = ("view", "reshape", "expand", "t.default", "transpose", "unsqueeze", "squeeze", "select", "slice",
           "as_strided", "detach", "alias", "permute", "_unsafe_view", "lift_fresh", "empty", "split",
           "unbind", "_to_copy", "clone", "copy_", "zeros", "ones", "full", "scalar_tensor", "item",
           "_local_scalar_dense", "nonzero", "unique", "arange", "randperm", "rand", "normal")
PARTS = [  # (key, label) in the table's order
    ("draw", "draw queries (uv, level, half/difference wi wo)"),
    ("lobe", "lobe directions (reference sampler, 10% of rows)"),
    ("graph", "targets: material graph at footprint points"),
    ("brdf", "targets: reference BRDF (cone MIS: sample, pdf, eval x2)"),
    ("targets_rest", "targets: footprint offsets, grouping, means"),
    ("latent", "encoder forward (phase 1) / latent fetch (phase 2)"),
    ("decoder", "decoder forward (BRDF loss + KL weights)"),
    ("sampler", "sampler forward, proxy sampling, KL and log-L1 losses"),
    ("backward", "backward (encoder, decoder, sampler)"),
    ("optim", "optimiser (grad clip + Adam)"),
    ("other", "rest of the step (Python, bookkeeping)"),
]


class Sections:
    """Exclusive wall time and FLOPs per named section; sections nest (a child's time and FLOPs are
    its own, not its parent's)."""

    def __init__(self):
        self.stack: list[str] = []
        self.time = defaultdict(float)
        self.cpu = defaultdict(float)
        self.flops = defaultdict(float)
        self.mm_flops = defaultdict(float)
        self.ops = defaultdict(int)

    @contextlib.contextmanager
    def section(self, name: str):
        self.stack.append(name)
        t, c = time.perf_counter(), time.process_time()
        child_before = self._child_total
        self._child_total = (0.0, 0.0)
        try:
            yield
        finally:
            dt, dc = time.perf_counter() - t, time.process_time() - c
            self.time[name] += dt - self._child_total[0]
            self.cpu[name] += dc - self._child_total[1]
            self.stack.pop()
            self._child_total = (child_before[0] + dt, child_before[1] + dc)

    _child_total = (0.0, 0.0)

    def current(self) -> str:
        return self.stack[-1] if self.stack else "other"

    def wrap(self, name: str, fn):
        def wrapped(*a, **k):
            with self.section(name):
                return fn(*a, **k)
        return wrapped


class FlopMode(TorchDispatchMode):
    """Counts 2MNK per matrix product and one FLOP per output element of other work into the current section."""

    def __init__(self, sections: Sections):
        super().__init__()
        self.s = sections

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        name = str(func)
        part = self.s.current()
        self.s.ops[part] += 1
        if name in MATMULS:
            a, b = (args[1], args[2]) if name == "aten.addmm.default" else (args[0], args[1])
            f = 2.0 * a.shape[-2] * a.shape[-1] * b.shape[-1] * (a.shape[0] if a.dim() == 3 else 1)
            if name == "aten.addmm.default":
                f += a.shape[0] * b.shape[-1]
            self.s.flops[part] += f
            self.s.mm_flops[part] += f
        elif not any(w in name for w in NO_WORK):
            outs = out if isinstance(out, (tuple, list)) else (out,)
            self.s.flops[part] += sum(o.numel() for o in outs if isinstance(o, torch.Tensor) and o.is_floating_point())
        return out


def build(case: str, preset_name: str, seed: int = 0, **overrides):
    """(reference, stack, trainer) for ``case`` as ``bench_fidelity.train_and_model`` builds them."""
    asset, material = CASES[case]
    src = find_material(asset, material)
    compiled = compile_material(src.document, src.material)
    ref = ReferenceMaterial(compiled)
    cfg = preset(preset_name, seed=seed, **overrides)
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    return ref, stack, trainer_mod.Trainer(ref, stack, cfg, tempfile.mkdtemp())


def instrument(tr, s: Sections):
    """Wrap what ``tr.train_step`` calls so that ``s`` records each part (module docstring)."""
    for mod, fn in ((trainer_mod, "draw_uv"), (targets_mod, "sample_levels"), (trainer_mod, "half_difference_pairs")):
        setattr(mod, fn, s.wrap("draw", getattr(mod, fn)))
    trainer_mod.lobe_directions = s.wrap("lobe", trainer_mod.lobe_directions)
    tr._targets = s.wrap("targets_rest", tr._targets)
    ref = tr.ref
    ref.parameters_at = s.wrap("graph", ref.parameters_at)
    for m in ("sample", "pdf", "eval"):  # inside lobe_directions these stay the lobe's (see below)
        orig = getattr(ref, m)

        def brdf(*a, _orig=orig, **k):
            name = "brdf" if s.current() in ("targets_rest", "brdf") else s.current()
            with s.section(name):
                return _orig(*a, **k)
        setattr(ref, m, brdf)
    tr._latent = s.wrap("latent", tr._latent)
    tr.model.decoder.forward = s.wrap("decoder", tr.model.decoder.forward)
    tr.model.sampler.forward = s.wrap("sampler", tr.model.sampler.forward)
    tr._losses = s.wrap("sampler", tr._losses)  # what the losses do besides the two networks: the proxy, KL
    orig_backward = torch.Tensor.backward
    torch.Tensor.backward = lambda self, *a, **k: s.wrap("backward", orig_backward)(self, *a, **k)
    orig_clip = torch.nn.utils.clip_grad_norm_
    torch.nn.utils.clip_grad_norm_ = s.wrap("optim", orig_clip)
    tr.opt.step = s.wrap("optim", tr.opt.step)


def profile_phase(tr, s: Sections, steps: int, flops: bool) -> dict:
    """Per-step figures over ``steps`` steps: ``ms``, ``cpu_ms`` (process CPU time), ``flops``,
    ``mm_flops``, ``ops`` (aten calls; with ``flops`` only), each by part; ``total`` and ``cpu_total`` ms."""
    for d in (s.time, s.cpu, s.flops, s.mm_flops, s.ops):
        d.clear()
    t, c = time.perf_counter(), time.process_time()
    with FlopMode(s) if flops else contextlib.nullcontext():
        for _ in range(steps):
            with s.section("other"):
                tr.train_step()
    per = {"ms": s.time, "cpu_ms": s.cpu, "flops": s.flops, "mm_flops": s.mm_flops, "ops": s.ops}
    out = {k: {p: v / steps * (1e3 if k.endswith("ms") else 1) for p, v in d.items()} for k, d in per.items()}
    out["total"] = (time.perf_counter() - t) / steps * 1e3
    out["cpu_total"] = (time.process_time() - c) / steps * 1e3
    return out


def best_time(fn, repeats: int = 5, number: int = 3) -> float:
    fn()
    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t) / number)
    return best


def flop_rates(batch: int) -> dict:
    """GFLOP/s (FP32) of the decoder's hidden layer as addmm [batch,64]x[64,64] (+ bias), of a 2048²
    matmul, and of elementwise a*b+c and exp on 2^20 floats (2 and 1 FLOPs per element)."""
    g = torch.Generator().manual_seed(0)
    x, w, bias = torch.randn(batch, 64, generator=g), torch.randn(64, 64, generator=g), torch.randn(64, generator=g)
    big_a, big_b = torch.randn(2048, 2048, generator=g), torch.randn(2048, 2048, generator=g)
    e = [torch.rand(1 << 20, generator=g) for _ in range(3)]
    out = torch.empty(1 << 20)
    small = torch.rand(32768, 1, generator=g)
    tiny = torch.rand(1, 1, generator=g)
    return {
        "op on [1,1] (us/op)": best_time(lambda: tiny * 2.0, number=200) * 1e6,
        "op on [32768,1] (us/op)": best_time(lambda: small * 2.0, number=200) * 1e6,
        "decoder layer (addmm)": 2 * batch * 64 * 64 / best_time(lambda: torch.addmm(bias, x, w), number=50) / 1e9,
        "square 2048² matmul": 2 * 2048 ** 3 / best_time(lambda: big_a @ big_b, repeats=3, number=1) / 1e9,
        "elementwise a*b+c": 2 * (1 << 20) / best_time(lambda: torch.addcmul(e[2], e[0], e[1], out=out),
                                                      number=20) / 1e9,
        "elementwise exp": (1 << 20) / best_time(lambda: torch.exp(e[0], out=out), number=20) / 1e9,
    }


def mlp_flops(in_dim: int, hidden: tuple[int, ...], out_dim: int, rows: int) -> float:
    """Forward FLOPs of ``mlp(in_dim, hidden, out_dim)`` on ``rows`` rows: 2 per weight (multiply-add) + bias."""
    dims = (in_dim, *hidden, out_dim)
    return rows * sum(2 * a * b + b for a, b in zip(dims, dims[1:]))


def analytic_mlp_table(tr) -> list[tuple[str, float]]:
    """Per-step FLOPs of the networks from their layer shapes (forward, and backward = 2x forward
    where inputs need gradients, weights-only 1x for the no-grad passes)."""
    cfg = tr.cfg
    b = cfg.batch + round(cfg.grazing_fraction * cfg.batch)
    hid = parse_hidden(cfg.decoder)
    d_in = 2 * 3 * max(cfg.frames, 1) + cfg.latent_dim
    dec = mlp_flops(d_in, hid, 3, b) + 2 * b * cfg.latent_dim * 6 * cfg.frames
    enc_in = max(tr.stack.levels[0].shape[0], 1)
    enc = mlp_flops(enc_in, (64, 64, 64), cfg.latent_dim, b)
    smp = mlp_flops(3 + cfg.latent_dim, (32, 32, 32), 9, b)
    return [("decoder: BRDF pass fwd + bwd (3x)", 3 * dec), ("decoder: KL-weight pass (no grad)", dec),
            ("sampler: proposal pass (no grad) + pdf pass fwd + bwd", smp + 3 * smp),
            ("encoder fwd + bwd (phase 1 only)", 3 * enc)]


def isolated_backward_split(tr) -> dict:
    """ms of forward + backward of each network alone on the step's shapes (phase 1)."""
    cfg = tr.cfg
    b = cfg.batch
    g = torch.Generator().manual_seed(1)
    raw = torch.rand(b, max(tr.stack.levels[0].shape[0], 1), generator=g)
    wi = torch.nn.functional.normalize(torch.rand(b, 3, generator=g) + 0.1, dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(b, 3, generator=g) + 0.1, dim=-1)
    m = tr.model
    enc, dec, smp = m.encoder, m.decoder, m.sampler
    for p in enc.parameters():  # frozen after the bake
        p.requires_grad_(True)

    def run(which):
        lat_src = raw if tr.textured else raw[:, :0]
        lat = enc(lat_src) if which == "encoder" else enc(lat_src).detach().requires_grad_(True)
        if which == "encoder":
            lat.sum().backward()
        elif which == "decoder":
            dec(lat, wi, wo).sum().backward()
        else:
            smp.pdf(wi, wo, lat.detach()).log().sum().backward()

    return {k: best_time(lambda k=k: run(k)) * 1e3 for k in ("encoder", "decoder", "sampler")}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", default="GlazedCeramic", choices=list(CASES))
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--steps", type=int, default=8, help="timed steps per phase and thread count")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a TrainConfig field of the preset, e.g. footprint_one_call=1")
    ap.add_argument("--out", type=Path, help="also write the tables (Markdown) here")
    args = ap.parse_args()
    overrides = config_overrides(args.set, ap)
    if not TEXTURED.exists():
        import subprocess

        subprocess.run([sys.executable, str(TEXTURED.parents[1] / "make_textured_sample.py")], check=True)
    threads = [int(t) for t in args.threads.split(",")]
    lines = []

    def emit(line=""):
        print(line, flush=True)
        lines.append(line)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    t0 = time.perf_counter()
    ref, stack, tr = build(args.case, args.preset, **overrides)
    build_s = time.perf_counter() - t0
    cfg = tr.cfg
    emit(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, load average "
         f"{load:.1f} at start; {args.case} (grid {stack.resolution[1]}x{stack.resolution[0]}, "
         f"{stack.levels[0].shape[0]} channels, texel ratio {stack.texel_ratio}), preset {args.preset} "
         f"(batch {cfg.batch}, decoder {cfg.decoder}, footprint_samples {cfg.footprint_samples}); "
         f"{args.steps} timed steps per phase after {args.warmup}; setup {build_s:.1f} s"
         + "".join(f"; {o}" for o in args.set))
    s = Sections()
    instrument(tr, s)
    res = {}  # (threads, phase) -> profile_phase's figures
    for phase in ("encoder", "finetune"):
        if phase == "finetune":
            tr.bake()
            tr.step = int(cfg.iterations * cfg.encoder_fraction)
        else:
            tr.step = 0
        for k in threads:
            torch.set_num_threads(k)
            for _ in range(args.warmup):
                tr.train_step()
            res[k, phase] = profile_phase(tr, s, args.steps, flops=False)
        torch.set_num_threads(threads[0])
        res["flops", phase] = profile_phase(tr, s, 2, flops=True)
    base = threads[0]

    def mix(key, field, part=None):  # the run's mean: phase 1 for encoder_fraction of the steps, then phase 2
        def one(phase):
            d = res[key, phase][field]
            return d if part is None else d.get(part, 0.0)
        return cfg.encoder_fraction * one("encoder") + (1 - cfg.encoder_fraction) * one("finetune")

    emit()
    emit("| part | " + " | ".join(f"ms/step, {k} thr: wall (CPU)" for k in threads)
         + " | FLOPs/step (of which matmul) | aten ops/step | share of wall, 1 thr |")
    emit("|---|" + "---|" * (len(threads) + 3))
    for key, label in PARTS:
        cells = [f"{mix(k, 'ms', key):.1f} ({mix(k, 'cpu_ms', key):.1f})" for k in threads]
        emit(f"| {label} | " + " | ".join(cells) + f" | {mix('flops', 'flops', key) / 1e6:.1f} M "
             f"({mix('flops', 'mm_flops', key) / 1e6:.1f} M) | {mix('flops', 'ops', key):.0f} | "
             f"{mix(base, 'ms', key) / mix(base, 'total'):.0%} |")
    fl_total = sum(mix("flops", "flops", p) for p, _ in PARTS)
    mm_total = sum(mix("flops", "mm_flops", p) for p, _ in PARTS)
    ops_total = sum(mix("flops", "ops", p) for p, _ in PARTS)
    cells = [f"**{mix(k, 'total'):.1f}** ({mix(k, 'cpu_total'):.1f})" for k in threads]
    emit("| **step** | " + " | ".join(cells) + f" | **{fl_total / 1e6:.1f} M** ({mm_total / 1e6:.1f} M) | "
         f"{ops_total:.0f} | 100% |")
    emit()
    emit("Phase 1 (encoder) / phase 2 (fine-tuning) step, wall ms: " + "; ".join(
        f"{k} thr {res[k, 'encoder']['total']:.1f} / {res[k, 'finetune']['total']:.1f}" for k in threads)
        + f"; the run's mean weights them {cfg.encoder_fraction:g} / {1 - cfg.encoder_fraction:g}.")
    emit("Networks from layer shapes (FLOPs/step, batch "
         f"{cfg.batch}): " + "; ".join(f"{n} {v / 1e6:.1f} M" for n, v in analytic_mlp_table(tr)) + ".")
    torch.set_num_threads(base)
    split = isolated_backward_split(tr)
    emit(f"Each network alone, forward + backward on the step's shapes, {base} thr: "
         + ", ".join(f"{k} {v:.1f} ms" for k, v in split.items()) + ".")

    emit()
    emit("| FP32 rate | " + " | ".join(f"{k} thr" for k in threads) + " |")
    emit("|---|" + "---|" * len(threads))
    rates = {}
    for k in threads:
        torch.set_num_threads(k)
        rates[k] = flop_rates(cfg.batch)
    for name in rates[base]:
        unit = "" if "us/op" in name else " (GFLOP/s)"
        emit(f"| {name}{unit} | " + " | ".join(f"{rates[k][name]:.1f}" for k in threads) + " |")

    emit()
    for k in threads:
        r = rates[k]
        step = mix(k, "total")
        floor_square = fl_total / (r["square 2048² matmul"] * 1e9) * 1e3
        floor_mixed = (mm_total / (r["decoder layer (addmm)"] * 1e9)
                       + (fl_total - mm_total) / (r["elementwise a*b+c"] * 1e9)) * 1e3
        floor_ops = ops_total * r["op on [1,1] (us/op)"] * 1e-3
        emit(f"- {k} thr: step {step:.1f} ms. Floor if every FLOP ran at the square-matmul rate: "
             f"{floor_square:.2f} ms ({step / floor_square:.0f}x below the step); matmuls at the decoder-shape "
             f"rate and the rest at the elementwise rate: {floor_mixed:.1f} ms ({step / floor_mixed:.1f}x); "
             f"{ops_total:.0f} aten calls at the [1,1] op's cost: {floor_ops:.1f} ms.")
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
