"""Generate the Slang module of one neural material from its trained networks.

``generate_slang(model_or_export_dir, name)`` returns the text of ``NeuralMaterial_<name>.slang``.
It fills the templates in ``codegen/templates/`` and imports the runtime modules
``NeuralMaterial`` and ``NeuralLayers`` from ``codegen/slang/`` (see :mod:`.paths`). The networks'
code comes from :func:`.network_emitter.emit_mlp` (one storage per path below), their weight orders
and binaries from :mod:`.weight_layout`.

Weight storage choices (documented in the module header too):

- **Divergent FP16 path**: weights baked into the shader as ``static const half2`` arrays *in
  access order* (per neuron pair: the bias pair, then one weight pair per input), consumed by
  a fully unrolled sequence of packed half2 FMAs. After unrolling every array index is a
  compile-time constant, so the compiler turns each weight into an immediate / constant-bank
  operand: no per-lane loads, which is what divergent warps need. The same arrays are also
  written as a binary (:func:`fp16_blob`) for the buffer-loaded variant (``*_FP16Buffer``),
  which lets engines share one shader between materials.
- **Coherent path**: cooperative vectors need the matrices in memory. :func:`coopvec_blob`
  lays each layer out row-major with rows padded to 16 bytes (matrices 64-byte aligned, biases
  16-byte aligned); engines convert each matrix to the InferencingOptimal layout with the
  graphics API's conversion call and keep the offsets (or regenerate with their own).
- **FP32 variant**: the float32 weights as trained (from an export folder: its FP16 values),
  for exact checks against the torch model.

Emission and opacity: every module ends with ``<prefix>_Surface<M : INMSurfaceMap>`` whose
``emission(uv, lod)`` and ``opacity(uv, lod)`` bake in the material's constants or read its
``emission.exr`` / ``opacity.exr`` trilinearly (templates/surface.slang.in, :func:`_surface_section`).

Network inputs follow the torch model (:mod:`mtlx2neural.model.decoder`): decoder ``[wi in
each frame (t, b, n), wo likewise, latent]`` (raw ``wi, wo`` without frames), albedo head
``[wi in each frame, latent]``, sampler ``[wi, latent]``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from string import Template

import numpy as np

from mtlx2neural.codegen.network_emitter import (
    SLANG,
    CoopMatTiles,
    CoopVecMatrices,
    Stream16,
    Stream32,
    describe,
    emit_mlp,
)
from mtlx2neural.codegen.paths import template
from mtlx2neural.codegen.spec import NetworkSpec, SurfaceSpec, as_spec, surface_spec
from mtlx2neural.codegen.weight_layout import (
    COOPMAT_TILE,
    coopmat_blob,
    coopvec_blob,
    fp16_blob,
    stream16,
    stream32,
)
from mtlx2neural.formats.latent_codec import binding_comment, codec_of
from mtlx2neural.formats.weights import ENVIRONMENT_OUTPUTS


def identifier(name: str) -> str:
    """A Slang identifier from a material name ('/World/Looks/Car Paint' -> 'Car_Paint')."""
    s = re.sub(r"\W+", "_", str(name).rstrip("/").rsplit("/", 1)[-1]).strip("_") or "Material"
    return s if not s[0].isdigit() else f"M{s}"


def _f32(x: float) -> str:
    s = f"{float(x):.9g}"  # 9 significant digits round-trip every float32 exactly
    return s if any(c in s for c in ".enai") else s + ".0"


def _f16(x: float) -> str:
    s = repr(float(np.float16(x)))  # the exact value of the half, which parses exactly
    return s + "h"


def _array(ctype: str, name: str, items: list[str], per_line: int = 8) -> str:
    lines = [", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line)] or ["0"]
    body = ",\n    ".join(lines)
    return f"public static const {ctype} {name}[{max(len(items), 1)}] = {{\n    {body}\n}};"


# ------------------------------------------------------------------------------------------
# Access-order weight streams
# ------------------------------------------------------------------------------------------

# ------------------------------------------------------------------------------------------
# Code
# ------------------------------------------------------------------------------------------

@dataclass
class _Ctx:
    p: str        # identifier prefix, e.g. NM_CarPaint
    c: int        # latent channels
    frames: int


def _inputs_function(ctx: _Ctx, name: str, with_wo: bool) -> str:
    """``<p>_<name>Inputs<W>(frameWeights, lat, wi[, wo], out float x[K])`` in FP32."""
    p, c, f = ctx.p, ctx.c, ctx.frames
    dirs = ["wi", "wo"] if with_wo else ["wi"]
    k = len(dirs) * 3 * max(f, 1) + c
    args = ", ".join(f"float3 {d}" for d in dirs)
    lines = [f"public void {p}_{name}Inputs<W : INMWeights32>(W fw, NMLatent<{c}> lat, {args}, out float x[{k}])", "{"]
    if f == 0:
        for j, d in enumerate(dirs):
            lines.append(f"    x[{3 * j}] = {d}.x; x[{3 * j + 1}] = {d}.y; x[{3 * j + 2}] = {d}.z;")
    else:
        lines.append(f"    float v[{6 * f}];")
        lines.append(f"    nmLinear32<{c}, {6 * f}>(fw, 0, lat.v, v);")
        for i in range(f):
            vs = ", ".join(f"v[{6 * i + j}]" for j in range(6))
            lines.append(f"    float3x3 f{i} = nmFrame({vs});")
        lines.append("    float3 q;")
        for j, d in enumerate(dirs):
            for i in range(f):
                o = 3 * (j * f + i)
                lines.append(f"    q = nmProject(f{i}, {d}); x[{o}] = q.x; x[{o + 1}] = q.y; x[{o + 2}] = q.z;")
    off = k - c
    lines.append(f"    NM_UNROLL for (int i = 0; i < {c}; i++) x[{off} + i] = lat.v[i];")
    lines.append("}")
    return "\n".join(lines)


def _sampler_inputs(ctx: _Ctx) -> str:
    c = ctx.c
    return "\n".join([
        f"public void {ctx.p}_samplerInputs(NMLatent<{c}> lat, float3 wi, out float x[{3 + c}])", "{",
        "    x[0] = wi.x; x[1] = wi.y; x[2] = wi.z;",
        f"    NM_UNROLL for (int i = 0; i < {c}; i++) x[3 + i] = lat.v[i];", "}"])


_RGB = "return float3(nmOutputActivation(y[0]), nmOutputActivation(y[1]), nmOutputActivation(y[2]));"
_RGB_COS = _RGB[:-1] + " * max(wo.z, 0.0);"  # analytic_cosine: the network predicts f, the cosine is exact


def _network_functions(ctx: _Ctx, spec32: NetworkSpec, spec16: NetworkSpec, layout: dict | None) -> str:
    p, c = ctx.p, ctx.c
    lat = f"NMLatent<{c}> lat"
    kinds = {  # network -> (signature args, inputs call (fp32 frame weights placeholder), output)
        "decoder": ("decode", "float3", "float3 wi, float3 wo", f"{p}_decoderInputs({{fw}}(), lat, wi, wo, x)",
                    _RGB_COS if spec32.analytic_cosine else _RGB,
                    spec32.decoder_inputs),
        "albedo": ("albedo", "float3", "float3 wi", f"{p}_albedoInputs({{fw}}(), lat, wi, x)", _RGB,
                   3 * max(ctx.frames, 1) + c),
        "sampler": ("proxy", "NMProxy", "float3 wi", f"{p}_samplerInputs(lat, wi, x)", "return nmProxyFromRaw(y);",
                    3 + c),
    }
    nets32, nets16 = dict(spec32.networks()), dict(spec16.networks())
    out = []
    for net, (fn, rtype, args, inputs, ret, k) in kinds.items():
        if net not in nets32:  # no albedo head: stubs
            out.append(f"public {rtype} {p}_{fn}32({lat}, {args}) {{ return float3(0.0); }}")
            out.append(f"public {rtype} {p}_{fn}16<W : INMWeights16>(W w, {lat}, {args}) {{ return float3(0.0); }}")
            if layout is not None:
                out.append(f"public {rtype} {p}_{fn}Coop(ByteAddressBuffer wb, uint base, {lat}, {args}) "
                           f"{{ return float3(0.0); }}")
            continue
        tag = {"decoder": "Dec", "albedo": "Alb", "sampler": "Smp"}[net]
        body, cur = emit_mlp(describe(net, nets32[net]), Stream32(f"{p}_{tag}32()"), SLANG, "x")
        out += [f"public {rtype} {p}_{fn}32({lat}, {args})", "{", f"    float x[{k}]; " + inputs.format(fw=f"{p}_Frame32") + ";",
                *body, f"    float y[{nets32[net][-1].shape[0]}] = {cur};", f"    {ret}", "}", ""]
        net16 = describe(net, nets16[net])
        body16, _ = emit_mlp(net16, Stream16("w"), SLANG, "xh")
        out += [f"public {rtype} {p}_{fn}16<W : INMWeights16>(W w, {lat}, {args})", "{",
                f"    float x[{k}]; " + inputs.format(fw=f"{p}_Frame16") + ";",
                f"    half xh[{k}]; nmToHalfArray<{k}>(x, xh);", *body16, f"    {ret}", "}", ""]
        if layout is not None:
            body_cv, _ = emit_mlp(net16, CoopVecMatrices(layout[net]), SLANG, "xv")
            out += [f"public {rtype} {p}_{fn}Coop(ByteAddressBuffer wb, uint base, {lat}, {args})", "{",
                    f"    float x[{k}]; " + inputs.format(fw=f"{p}_Frame16") + ";",
                    f"    CoopVec<half, {k}> xv = nmCoopFromFloat<{k}>(x);",
                    *body_cv, f"    {ret}", "}", ""]
    return "\n".join(out)


def _environment_head(ctx: _Ctx, spec32: NetworkSpec, spec16: NetworkSpec) -> str:
    """The environment head in the module (its weights as constants, in access order): ``<p>_lobes32`` and
    ``<p>_lobes16<W>`` give the reflectance of the sharp lobe and the proxy's specular and diffuse lobes at ``wi``, from the
    albedo head's inputs; zero without a head. Every FP16 variant evaluates it from the constants
    (``<p>_Env16``): it runs once per shading point, so it has no buffer or cooperative form."""
    p, c = ctx.p, ctx.c
    head = f"NMLatent<{c}> lat, float3 wi, out float3 cSharp, out float3 cSpec, out float3 cDiff"
    zero = "{ cSharp = float3(0.0); cSpec = float3(0.0); cDiff = float3(0.0); }"
    if not spec32.environment:
        return "\n".join([f"public struct {p}_Env16 : INMWeights16 {{ public half2 w2(int i) {{ return half2(half(0.0)); }} }}",
                          f"public void {p}_lobes32({head}) {zero}",
                          f"public void {p}_lobes16<W : INMWeights16>(W w, {head}) {zero}"])
    k = 3 * max(ctx.frames, 1) + c
    ret = "\n".join(f"    {name} = float3({', '.join(f'nmOutputActivation(y[{3 * k + i}])' for i in range(3))});"
                    for k, name in enumerate(("cSharp", "cSpec", "cDiff")))
    v32, _ = stream32(spec32.environment)
    v16, _ = stream16(spec16.environment)
    out = ["// environment head, FP32, per neuron: bias, weights",
           _array("float", f"{p}_ENV32", [_f32(v) for v in v32]),
           "// environment head, FP16 pairs, per neuron pair: bias pair, one pair per input",
           _array("half2", f"{p}_ENV16", [f"half2({_f16(a)}, {_f16(b)})" for a, b in v16], per_line=4),
           f"public struct {p}_Env32 : INMWeights32 {{ public float w(int i) {{ return {p}_ENV32[i]; }} }}",
           f"public struct {p}_Env16 : INMWeights16 {{ public half2 w2(int i) {{ return {p}_ENV16[i]; }} }}", ""]
    body, cur = emit_mlp(describe("environment", spec32.environment), Stream32(f"{p}_Env32()"), SLANG, "x")
    out += [f"public void {p}_lobes32({head})", "{", f"    float x[{k}]; {p}_albedoInputs({p}_Frame32(), lat, wi, x);",
            *body, f"    float y[{ENVIRONMENT_OUTPUTS}] = {cur};", ret, "}", ""]
    body16, _ = emit_mlp(describe("environment", spec16.environment), Stream16("w"), SLANG, "xh")
    out += [f"public void {p}_lobes16<W : INMWeights16>(W w, {head})", "{",
            f"    float x[{k}]; {p}_albedoInputs({p}_Frame16(), lat, wi, x);",
            f"    half xh[{k}]; nmToHalfArray<{k}>(x, xh);", *body16, ret, "}"]
    return "\n".join(out)


def _coopmat_functions(ctx: _Ctx, spec32: NetworkSpec, layout: dict) -> str:
    """``<p>_decodeCM`` / ``_proxyCM`` / ``_albedoCM``: the networks on cooperative matrices
    (templates/coopmat.slang.in), weights from the .coopmat.bin ``layout``."""
    p, c = ctx.p, ctx.c
    lat, tile = f"NMLatent<{c}> lat", "NMCoopMatTile t"
    kinds = {"decoder": ("decode", "float3", "float3 wi, float3 wo", f"{p}_decoderInputs({p}_Frame16(), lat, wi, wo, x)",
                         _RGB_COS if spec32.analytic_cosine else _RGB),
             "albedo": ("albedo", "float3", "float3 wi", f"{p}_albedoInputs({p}_Frame16(), lat, wi, x)", _RGB),
             "sampler": ("proxy", "NMProxy", "float3 wi", f"{p}_samplerInputs(lat, wi, x)", "return nmProxyFromRaw(y);")}
    out, nets = [], dict(spec32.networks())
    for net, (fn, rtype, args, inputs, ret) in kinds.items():
        head = f"public {rtype} {p}_{fn}CM(ByteAddressBuffer wb, uint base, {tile}, {lat}, {args})"
        if net not in layout:
            out.append(head + " { return float3(0.0); }")
            continue
        entries = layout[net]
        k, kp = entries[0]["shape"][1], entries[0]["padded"][1]
        body = [f"    float x[{k}]; {inputs};", f"    {p}_cmStoreInputs<{k}, {kp}>(t, x);"]
        body += emit_mlp(describe(net, nets[net]), CoopMatTiles(entries, p), SLANG, "x")[0]
        out += [head, "{", *body, f"    {ret}", "}", ""]
    return "\n".join(out)


def _weights(ctx: _Ctx, spec32: NetworkSpec, spec16: NetworkSpec) -> tuple[str, str]:
    p, arrays, structs = ctx.p, [], []
    frames32 = spec32.frame.ravel() if spec32.frame is not None else np.zeros(1, np.float32)
    frames16 = spec16.frame.ravel() if spec16.frame is not None else np.zeros(1, np.float32)
    for tag, vals in (("FRAME32", frames32), ("FRAME16", frames16)):
        arrays.append(f"// frame layer [{6 * ctx.frames}, {ctx.c}] row-major, no bias"
                      + (" (FP16-rounded values)" if tag == "FRAME16" else ""))
        arrays.append(_array("float", f"{p}_{tag}", [_f32(v) for v in vals]))
        structs.append(f"public struct {p}_{tag.title()} : INMWeights32 "
                       f"{{ public float w(int i) {{ return {p}_{tag}[i]; }} }}")
    nets16 = dict(spec16.networks())
    for net, layers in spec32.networks():
        tag = {"decoder": "DEC", "albedo": "ALB", "sampler": "SMP"}[net]
        v32, _ = stream32(layers)
        shapes = " -> ".join([str(layers[0].shape[1])] + [str(l.shape[0]) for l in layers])
        arrays.append(f"// {net} {shapes}, FP32, per neuron: bias, weights")
        arrays.append(_array("float", f"{p}_{tag}32", [_f32(v) for v in v32]))
        v16, _ = stream16(nets16[net])
        arrays.append(f"// {net} {shapes}, FP16 pairs, per neuron pair: bias pair, one pair per input")
        arrays.append(_array("half2", f"{p}_{tag}16", [f"half2({_f16(a)}, {_f16(b)})" for a, b in v16], per_line=4))
    for tag in ("DEC", "ALB", "SMP"):
        name = tag.title()
        if tag == "ALB" and spec32.albedo is None:
            structs.append(f"public struct {p}_{name}32 : INMWeights32 {{ public float w(int i) {{ return 0.0; }} }}")
            structs.append(f"public struct {p}_{name}16 : INMWeights16 {{ public half2 w2(int i) {{ return half2(half(0.0)); }} }}")
            continue
        structs.append(f"public struct {p}_{name}32 : INMWeights32 {{ public float w(int i) {{ return {p}_{tag}32[i]; }} }}")
        structs.append(f"public struct {p}_{name}16 : INMWeights16 {{ public half2 w2(int i) {{ return {p}_{tag}16[i]; }} }}")
    return "\n".join(arrays), "\n".join(structs)


def generate_slang(model_or_export_dir, name: str | None = None, *, coherent: bool = True,
                   source: str | None = None, surface=None) -> str:
    """The Slang module ``NeuralMaterial_<name>`` for a NeuralMaterial, an export folder (its
    ``weights.json``/``weights.bin``) or a :class:`NetworkSpec`.

    ``coherent=False`` leaves out the cooperative-vector path (plain FP16 fallback for
    profiles without cooperative vectors). ``name`` defaults to the export folder's material
    folder name; ``source`` is recorded in the header. ``surface``: the emission and opacity
    (anything :func:`.spec.surface_spec` takes: a SurfaceSpec, SurfaceMaps, an export folder with its
    ``surface.json``); by default the export folder's or the model's ``surface``. Every module has
    ``<prefix>_Surface<M>`` with ``emission(uv, lod)`` and ``opacity(uv, lod)`` (:func:`_surface_section`)."""
    version = _version()

    spec32 = as_spec(model_or_export_dir)
    spec16 = spec32.fp16()
    if name is None:
        if not isinstance(model_or_export_dir, (str, Path)):
            raise ValueError("give the material name for a model in memory")
        folder = Path(model_or_export_dir)
        name = (folder.parent if folder.name in ("neural", "weights.json") else folder).name
    ident = identifier(name)
    ctx = _Ctx(f"NM_{ident}", spec32.latent_channels, spec32.frames)
    arrays, structs = _weights(ctx, spec32, spec16)
    layout = coopvec_blob(spec32)[1] if coherent else None
    _, offsets16 = fp16_blob(spec32)
    inputs = [_inputs_function(ctx, "decoder", True), _inputs_function(ctx, "albedo", False), _sampler_inputs(ctx)]
    coherent_doc = (f"//   {ctx.p}_CoopVec  coherent path: CoopVec matrix-vector products (coopVecMatMulAdd,\n"
                    "//                      InferencingOptimal layout) on the .coopvec.bin weights.\n"
                    f"//   {ctx.p}         per-warp selection of the coherent or the divergent path."
                    if coherent else f"//   {ctx.p}         the divergent FP16 path (no cooperative vectors).")
    subs = {
        "module": f"NeuralMaterial_{ident}", "material": str(name), "version": version, "prefix": ctx.p,
        "material_type": f"NeuralMaterial_{ident}", "source": source or _describe_source(model_or_export_dir),
        "channels": ctx.c, "frames": ctx.frames,
        "latent_binding": binding_comment(codec_of(model_or_export_dir), ctx.c),
        "decoder_arch": "x".join(map(str, spec32.decoder_hidden)) or "linear",
        "sampler_arch": "x".join(map(str, spec32.sampler_hidden)) or "linear",
        "albedo_head": "yes" if spec32.albedo else "no", "has_albedo": "true" if spec32.albedo else "false",
        "arrays": arrays, "weight_structs": structs, "input_functions": "\n\n".join(inputs),
        "network_functions": _network_functions(ctx, spec32, spec16, layout) + "\n\n"
        + _environment_head(ctx, spec32, spec16),
        "environment_head": "yes" if spec32.environment else "no",
        "has_environment": "true" if spec32.environment else "false",
        "dec16_offset": f"{offsets16['decoder']}u", "smp16_offset": f"{offsets16['sampler']}u",
        "alb16_offset": f"{offsets16.get('albedo', 0)}u", "coherent_doc": coherent_doc,
        "fp16_notes": "".join(f"// FP16 note: {n}\n" for n in spec16.notes),
        "coopvec_layout": _layout_comment(layout, offsets16, coopmat_blob(spec32)[1]),
    }
    cm_layout = coopmat_blob(spec32)[1]
    subs["tile"] = COOPMAT_TILE
    subs["cm_width"] = max(max(e["padded"]) for entries in cm_layout.values() for e in entries)
    subs["coopmat_functions"] = _coopmat_functions(ctx, spec32, cm_layout)
    subs["coherent_structs"] = (Template(template("coherent.slang.in" if coherent else "fallback.slang.in")).substitute(subs)
                                + Template(template("coopmat.slang.in")).substitute(subs))
    text = Template(template("material.slang.in")).substitute(subs)
    text += _surface_section(subs, surface_spec(model_or_export_dir if surface is None else surface))
    return text + _udim_table(ctx, spec32.udim_tiles) if spec32.udim_tiles else text


def _surface_section(subs: dict, surface: SurfaceSpec | None) -> str:
    """``<prefix>_Surface<M : INMSurfaceMap>`` (templates/surface.slang.in): ``emission(uv, lod)`` and
    ``opacity(uv, lod)`` of ``surface`` (None: emits nothing, opaque); constants are baked in, textured
    maps read from the struct's ``emissionMap`` / ``opacityMap`` (bound to ``emission.exr`` /
    ``opacity.exr``), trilinearly; a cut-out's opacity alpha-tested at 0.5."""
    s = surface or SurfaceSpec()
    p, cutoff = subs["prefix"], s.alpha_cutoff
    if s.emission_file is not None:
        emission_doc = f"textured: {s.emission_file} (RGB, {s.levels} MIP levels, linear working-space RGB)."
        emission_body = "return emissionMap.sampleLod(uv, lod).xyz;"
    elif s.emission_constant is not None:
        rgb = ", ".join(_f32(v) for v in s.emission_constant)
        emission_doc, emission_body = f"constant ({rgb}).", f"return float3({rgb});"
    else:
        emission_doc, emission_body = "none (0).", "return float3(0.0);"
    if s.opacity_file is not None:
        read = "opacityMap.sampleLod(uv, lod).x"
        opacity_doc = (f"textured: {s.opacity_file} (one channel, {s.levels} MIP levels), "
                       + ("a cut-out: alpha-tested at 0.5 (coverage-preserving levels)." if cutoff is not None
                          else "blended: the value, clamped to [0, 1]."))
        opacity_body = (f"return ({read} >= {p}_ALPHA_CUTOFF) ? 1.0 : 0.0;" if cutoff is not None
                        else f"return clamp({read}, 0.0, 1.0);")
    elif s.opacity_constant is not None:
        value = _f32(s.coverage_constant)
        opacity_doc = (f"constant {_f32(s.opacity_constant)} ({s.alpha_mode}" +
                       (f": alpha-tested to {value})." if cutoff is not None else ")."))
        opacity_body = f"return {value};"
    else:
        opacity_doc, opacity_body = "opaque (1).", "return 1.0;"
    width, height = s.size or (0, 0)
    return Template(template("surface.slang.in")).substitute(
        subs, emission_doc=emission_doc, opacity_doc=opacity_doc, emission_body=emission_body,
        opacity_body=opacity_body, emits="true" if s.emits else "false",
        emission_textured="true" if s.emission_file else "false",
        opacity_textured="true" if s.opacity_file else "false",
        alpha_mode={"opaque": 0, "mask": 1, "blend": 2}[s.alpha_mode], levels=s.levels if s.textured else 0,
        width=_f32(width), height=_f32(height),
        emission_binding=f"bind {s.emission_file} (RGB)" if s.emission_file else "not read (constant or none)",
        opacity_binding=f"bind {s.opacity_file} (one channel)" if s.opacity_file else "not read (constant or opaque)")


def _udim_table(ctx: _Ctx, tiles: list[int]) -> str:
    """The tile table of a UDIM material (docs/ARCHITECTURE.md, "UDIM latents"): its UDIM numbers in
    slot order (slot k = layer k of the latent texture arrays, tile k of NMBufferTiledLatents) and
    ``<prefix>_udimSlot(uv)``, the slot of uv's tile or -1 for a tile it was not trained on."""
    p, n = ctx.p, len(tiles)
    items = ", ".join(str(int(t)) for t in tiles)
    return f"""
// ---------------------------------------------------------------------------------------------
// UDIM tiles: one latent pyramid per tile, read at frac(uv) with clamp-to-edge addressing.
// Bind the latents as texture arrays whose layer k holds tile {p}_TILES[k] (NMTextureArrayLatents8,
// files latents_<g>.<UDIM>.exr), or as NMBufferTiledLatents; fetch with
// nmFetchLatentTiled(source, slot, uv, lod, u) where slot = {p}_udimSlot(uv). A uv in no trained
// tile gives slot -1: the material is not defined there; shade it black (eval 0, no sample).
// ---------------------------------------------------------------------------------------------
public static const int {p}_TILE_COUNT = {n};
public static const int {p}_TILES[{n}] = {{ {items} }};

public int {p}_udimSlot(float2 uv)
{{
    int udim = nmUdimOfUv(uv);
    for (int k = 0; k < {p}_TILE_COUNT; k++)
        if ({p}_TILES[k] == udim)
            return k;
    return -1;
}}
"""


def _layout_comment(layout: dict | None, offsets16: dict, cm_layout: dict) -> str:
    lines = ["// Weight binaries: .fp16.bin holds the FP16 access-order arrays of the networks at byte offsets "
             + ", ".join(f"{k} {v}" for k, v in offsets16.items()) + "."]
    if layout is not None:
        lines.append("// .coopvec.bin (coherent path), FP16 row-major; per layer: [out, in], matrix offset, "
                     "row stride, bias offset (bytes):")
        for net, entries in layout.items():
            lines.append(f"//   {net}: " + "; ".join(f"[{e['shape'][0]}, {e['shape'][1]}] @{e['matrix']} "
                                                  f"stride {e['row_stride']} bias @{e['bias']}" for e in entries))
    lines.append(f"// .coopmat.bin (cooperative matrices), FP16; per layer W [out, in] zero-padded to multiples of "
                 f"{COOPMAT_TILE}, row-major\n// (= B = W^T column-major, stride = padded in), then the bias zero-padded "
                 "to the padded out; [out, in] -> [padded], matrix offset, bias offset (bytes):")
    for net, entries in cm_layout.items():
        lines.append(f"//   {net}: " + "; ".join(f"[{e['shape'][0]}, {e['shape'][1]}] -> [{e['padded'][0]}, {e['padded'][1]}] "
                                              f"@{e['matrix']} bias @{e['bias']}" for e in entries))
    return "\n".join(lines)


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("mtlx2neural")
    except Exception:  # noqa: BLE001  (not installed)
        return "(source checkout)"


def _describe_source(obj) -> str:
    if isinstance(obj, (str, Path)):
        return f"export {Path(obj)}"
    if isinstance(obj, NetworkSpec):
        return "network spec"
    return f"{type(obj).__name__} in memory (float32 weights)"
