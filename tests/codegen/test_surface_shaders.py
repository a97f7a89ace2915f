"""The generated Slang module's emission and opacity (``<prefix>_Surface``: codegen/README.md, "Emission
and opacity") on slangpy's CPU device against the torch reference, ``SurfaceMaps.emission`` / ``opacity``
with :func:`mtlx2neural.contract.coverage_of`.

Each material is a small seeded NeuralMaterial (8x8 latents: maps of 8, 4, 2 and 1 texels per side) whose
hand-made maps are written with ``write_surface_files`` beside its weights and read back with
``read_surface_files``: the module is generated from that export folder and both sides read the same
half-float values, so the comparison is float32-tight.

Level choice: the module reads the maps trilinearly (the mean of the stochastic choice between the two
nearest levels that the torch reference makes with ``u_level``). At integer lods (-1 and beyond the
coarsest level included: both clamp) there is nothing to choose and the torch reference is read with
``u_level`` 0; at fractional lods the reference is (1 - f) * (read with u_level 1: level floor(lod)) +
f * (read with u_level 0: level floor(lod) + 1). A cut-out's opacity is alpha-tested after the blend,
so its reference is the test of that blend.

Tolerance: 1e-5 relative (floor 1e-3): float32 bilinear weights and one blend on identical texels, only
rounding differs (measured max 1.0e-7). A cut-out's test could flip where the blended value lies within
rounding of the cutoff; the coverage-preserving coarse levels hold texels at exactly 0.5, so a third of the
points do (a uniform 0.5 region reads 0.5 or 0.49999997, by the rounding of the bilinear weights, in both):
there at most 0.5% may differ (measured: none of 1335).
"""

from __future__ import annotations

import gc

import numpy as np
import pytest
import torch

from mtlx2neural.codegen import as_spec, generate_slang, write_material_shader
from mtlx2neural.codegen.compile import find_slangc, slangc, spirv_val
from mtlx2neural.codegen.cpu import CpuMaterial, slangpy_available
from mtlx2neural.codegen.spec import read_surface_spec, surface_spec
from mtlx2neural.contract import ShadingPoint, coverage_of
from mtlx2neural.export.surface_files import (
    MANIFEST_FILE,
    read_surface_files,
    write_surface_files,
)
from mtlx2neural.formats.weights import write_weights
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.textures.surface_maps import (
    SurfaceMaps,
    coverage_preserving,
    level_shapes,
)

OK, REASON = slangpy_available()
needs_slangpy = pytest.mark.skipif(not OK, reason=f"slangpy CPU device unavailable: {REASON}")

N = 4096
TOL = 1e-5


def model() -> NeuralMaterial:
    torch.manual_seed(0)
    return NeuralMaterial((8, 8), in_dim=0, latent_dim=4, frames=0, decoder="2x16").train(False)


def textured_maps(kind: str) -> SurfaceMaps:
    """Seeded random maps on the 8x8 grid: emission (values up to 4, HDR) and a cut-out (``mask``,
    coverage-preserving levels) or a blended (``blend``, box-filtered) opacity."""
    g = torch.Generator().manual_seed(3)
    shapes = level_shapes(8, 8)
    emission = [torch.rand(3, h, w, generator=g) * 4 for h, w in shapes]
    if kind == "mask":
        covered = (torch.rand(1, 8, 8, generator=g) > 0.4).float()
        opacity = coverage_preserving(covered, len(shapes))
    else:
        opacity = [torch.rand(1, h, w, generator=g) for h, w in shapes]
    return SurfaceMaps(emission_levels=emission, opacity_levels=opacity, alpha_mode=kind)


MATERIALS = {
    "mask": lambda: textured_maps("mask"),
    "blend": lambda: textured_maps("blend"),
    "constant": lambda: SurfaceMaps(emission_constant=(2.5, 0.75, 0.125), opacity_constant=0.3, alpha_mode="blend"),
    "constant_mask": lambda: SurfaceMaps(emission_constant=(1.0, 2.0, 3.0), opacity_constant=0.0, alpha_mode="mask"),
}


def exported(folder, maps: SurfaceMaps | None):
    """An export folder (weights + the maps' files) and the maps read back from it (half values)."""
    m = model()
    write_weights(m, folder)
    write_surface_files(maps, folder)
    return folder, read_surface_files(folder)


def queries(seed: int = 1):
    """uv over [-1.5, 2.5]^2 (the maps wrap) and lods: integer ones from -1 to 5 (the coarsest level is
    3) on half the points, fractional ones from -0.5 to 4 on the rest."""
    g = torch.Generator().manual_seed(seed)
    uv = torch.rand(N, 2, generator=g) * 4 - 1.5
    lod = torch.randint(-1, 6, (N,), generator=g).float()
    lod[N // 2:] = torch.rand(N - N // 2, generator=g) * 4.5 - 0.5
    return uv, lod


def reference(maps: SurfaceMaps, uv, lod):
    """(emission [N, 3], opacity as a consumer uses it [N], the opacity map's blended value [N] or None):
    the trilinear mean of the two levels the torch reference chooses between (module docstring)."""
    levels = len(maps.emission_levels or maps.opacity_levels or [0])
    clamped = lod.clamp(0, levels - 1)
    f = (clamped - clamped.floor()).double()
    lo, hi = (ShadingPoint(uv=uv, lod=lod, u_level=torch.full((N,), u)) for u in (1.0, 0.0))

    def mean(fn):
        a, b = fn(lo), fn(hi)
        if a is None:
            return None
        w = f[:, None] if a.ndim == 2 else f
        return a.double() * (1 - w) + b.double() * w

    e = mean(maps.emission)
    alpha = mean(maps.opacity)
    if alpha is None:
        cover = torch.ones(N, dtype=torch.float64)
    elif maps.alpha_cutoff is not None:
        cover = (alpha >= maps.alpha_cutoff).double()
    else:
        cover = alpha.clamp(0, 1)
    return (torch.zeros(N, 3, dtype=torch.float64) if e is None else e), cover, alpha


def rel(a, b, floor=1e-3):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.abs(a - b) / np.maximum(np.abs(b), floor)


@needs_slangpy
@pytest.mark.parametrize("kind", list(MATERIALS))
def test_surface_functions_match_torch(kind, tmp_path):
    folder, maps = exported(tmp_path / "neural", MATERIALS[kind]())
    src = generate_slang(folder, "Surf")
    cm = CpuMaterial(src, "Surf", as_spec(folder), "FP32", workdir=tmp_path / "cg")
    uv, lod = queries()
    em = None if maps.emission_levels is None else [lv.numpy() for lv in maps.emission_levels]
    op = None if maps.opacity_levels is None else [lv.numpy() for lv in maps.opacity_levels]
    e, o = cm.surface(em, op, uv.numpy(), lod.numpy())
    ref_e, ref_o, alpha = reference(maps, uv, lod)
    integer = (lod == lod.round()).numpy()
    # At integer lods the trilinear read is the torch reference's own read, by coverage_of as consumers use it.
    at = ShadingPoint(uv=uv, lod=lod, u_level=torch.zeros(N))
    exact = coverage_of(maps, at)
    exact = np.ones(N) if exact is None else exact.numpy()
    err_e, err_o = rel(e, ref_e.numpy()).max(), rel(o, ref_o.numpy())
    near = np.zeros(N, bool) if alpha is None or maps.alpha_cutoff is None else \
        np.abs(alpha.numpy() - maps.alpha_cutoff) <= 1e-5
    print(f"{kind}: emission max rel error {err_e:.3g}, opacity {err_o[~near].max():.3g}; "
          f"{int(near.sum())} points within 1e-5 of the cutoff, {int((err_o[near] > TOL).sum())} of them differ")
    assert err_e <= TOL and err_o[~near].max() <= TOL
    assert (err_o[near] > TOL).sum() <= 0.005 * N
    assert rel(o[integer & ~near], exact[integer & ~near]).max() <= TOL
    if maps.alpha_cutoff is not None:
        assert set(np.unique(o).tolist()) <= {0.0, 1.0}
    if kind == "mask":
        assert 0.2 < o.mean() < 0.9  # both sides of the cut-out are met
    if maps.emission_levels is not None:  # the levels really differ: a wrong level choice would show
        assert rel(e[~integer], ref_e.numpy()[~integer]).max() <= TOL and np.ptp(e) > 1.0


@needs_slangpy
def test_material_without_maps_emits_nothing_and_is_opaque(tmp_path):
    folder, maps = exported(tmp_path / "neural", None)
    assert maps is None and not (folder / MANIFEST_FILE).exists()
    src = generate_slang(folder, "Plain")
    assert "public static const bool NM_Plain_EMITS = false;" in src and "NM_Plain_ALPHA_MODE = 0;" in src
    cm = CpuMaterial(src, "Plain", as_spec(folder), "FP32", workdir=tmp_path / "cg")
    uv, lod = queries()
    e, o = cm.surface(None, None, uv[:64].numpy(), lod[:64].numpy())
    assert np.all(e == 0) and np.all(o == 1)


@needs_slangpy
def test_harness_removes_its_own_temporary_folder(tmp_path):
    """Without a ``workdir`` the harness writes its module to a temporary folder of its own (the report's
    shader timing does, once per material) and removes it when collected, so runs leave nothing behind."""
    folder, _ = exported(tmp_path / "neural", None)
    cm = CpuMaterial(generate_slang(folder, "Temp"), "Temp", as_spec(folder), "FP32")
    work = cm.workdir
    assert (work / "NeuralMaterial_Temp.slang").is_file()
    del cm
    gc.collect()
    assert not work.exists()


def test_module_text_follows_the_manifest(tmp_path):
    """What the module says and bakes in: constants as float32 literals, the files to bind; the model's
    own ``surface`` when generated from a model; write_material_shader reads its folder's surface.json."""
    folder, _ = exported(tmp_path / "neural", MATERIALS["constant_mask"]())
    assert read_surface_spec(folder) is not None  # the codegen reads the manifest the export wrote
    src = generate_slang(folder, "C")
    assert "return float3(1.0, 2.0, 3.0);" in src and "NM_C_ALPHA_MODE = 1;" in src
    assert "return 0.0;" in src.split("public float opacity(float2 uv, float lod)")[1][:60]  # 0.0 < 0.5: cut away
    m = model()
    m.surface = textured_maps("mask")
    src = generate_slang(m, "T")
    assert "// bind emission.exr (RGB)" in src and "NM_T_SURFACE_LEVELS = 4u;" in src
    assert "(opacityMap.sampleLod(uv, lod).x >= NM_T_ALPHA_CUTOFF) ? 1.0 : 0.0" in src
    out = tmp_path / "out"
    write_surface_files(textured_maps("blend"), out)
    write_material_shader(model(), out, "W")
    text = (out / "NeuralMaterial_W.slang").read_text()
    assert "return clamp(opacityMap.sampleLod(uv, lod).x, 0.0, 1.0);" in text and "NM_W_ALPHA_MODE = 2;" in text
    spec = surface_spec(out)
    assert spec.size == (8, 8) and spec.levels == 4 and spec.alpha_mode == "blend"


KERNEL = """
import NeuralMaterial_Tex;
Texture2D<float4> gEmission;
Texture2D<float4> gOpacity;
SamplerState gTrilinearWrap;
RWStructuredBuffer<float4> gOut;
[shader("compute")]
[numthreads(32, 1, 1)]
void csSurface(uint3 t : SV_DispatchThreadID)
{
    NeuralMaterial_Tex_Surface s;
    s.emissionMap.texture = gEmission;
    s.emissionMap.trilinearWrap = gTrilinearWrap;
    s.emissionMap.numLevels = NM_Tex_SURFACE_LEVELS;
    s.opacityMap.texture = gOpacity;
    s.opacityMap.trilinearWrap = gTrilinearWrap;
    s.opacityMap.numLevels = NM_Tex_SURFACE_LEVELS;
    float2 uv = float2(t.x, t.y) / 64.0;
    gOut[t.x] = float4(s.emission(uv, 1.5), s.opacity(uv, 1.5));
}
"""


@pytest.mark.skipif(find_slangc() is None, reason="no slangc: set M2N_SLANGC, put slangc on PATH, or "
                                                   "pip install --no-deps slangtorch (ships slangc)")
def test_texture_maps_compile(tmp_path):
    """The texture path (NMTextureSurfaceMap: the exported EXRs with their MIP chains, SampleLevel with a
    trilinear sampler), which the CPU device does not run, compiles to HLSL and to SPIR-V that spirv-val
    accepts (where a spirv-val is installed)."""
    folder, _ = exported(tmp_path / "neural", textured_maps("mask"))
    write_material_shader(folder, folder, "Tex")
    (folder / "kernel.slang").write_text(KERNEL)
    hlsl = slangc(folder / "kernel.slang", "hlsl", entry="csSurface", profile="sm_6_2", include=[folder]).decode()
    assert "SampleLevel" in hlsl
    spv = slangc(folder / "kernel.slang", "spirv", entry="csSurface", include=[folder],
                 extra=["-emit-spirv-directly", "-O0"])
    status, msg = spirv_val(spv)
    assert status in ("ok", "missing"), msg
