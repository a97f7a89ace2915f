"""GLSL and Slang source of a neural material's MaterialX BSDF node, from its networks.

:func:`node_source` fills ``codegen/templates/neural_bsdf.glsl.in`` (MaterialX target
``genglsl``) or ``neural_bsdf.slang.in`` (``genslang``) with the same :class:`NetworkSpec` that
:mod:`.generate` turns into the Slang modules: the frame layer, the decoder MLP and the sampler
MLP in FP32, fully unrolled with every weight a literal (the shortest decimal that reads back as
the float32 weight; zero weights left out), written by :func:`.network_emitter.emit_mlp` in its
:class:`~.network_emitter.Literal` storage. Unrolled, nothing is indexed at run time: on Mesa's
llvmpipe a 3x64 decoder written as loops over constant arrays took 4.4x as long per frame (11.7 s
against 2.6 s at 256², 2 shared cores), a 2x32 one about as long. The hand-written parts of the templates (proxy
sampling and pdf, the level choice, the BSDF function) follow the Slang runtime
(``codegen/slang/NeuralMaterial.slang``) and the torch model line by line. MaterialX's own tokens
(``$envRadiance``, ...) are written ``$$name`` in the templates (``string.Template``'s escape).

The function follows MaterialX's closure contract (docs/notes/materialx-custom-bsdf.md):
``void <function>(ClosureData closureData, float weight, <one sampler per latent texture>,
vec2 texcoord, vec3 normal, vec3 tangent, int env_samples, bool env_prefiltered, inout BSDF bsdf)`` -- the nodedef's
inputs in order (:mod:`.materialx_node` writes that nodedef).

Every identifier is prefixed with the material's (``nm_<ident>_`` for functions, ``NM_<ident>``
for constants and structs), so several neural materials can share one shader.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from string import Template

import numpy as np

from mtlx2neural.codegen.generate import identifier
from mtlx2neural.codegen.network_emitter import (
    GLSL,
    SLANG,
    Literal,
    affine,
    describe,
    emit_mlp,
)
from mtlx2neural.codegen.paths import template
from mtlx2neural.codegen.spec import NetworkSpec
from mtlx2neural.errors import InputError
from mtlx2neural.model.proxy import SHARP_SOLID_ANGLE

LANGUAGES = {
    # target -> (template, type names, sampler type, the networks' syntax)
    "genglsl": ("neural_bsdf.glsl.in", {"vec2": "vec2", "vec3": "vec3", "vec4": "vec4"}, "sampler2D", GLSL),
    "genslang": ("neural_bsdf.slang.in", {"vec2": "float2", "vec3": "float3", "vec4": "float4"}, "SamplerTexture2D",
                 SLANG),
}
"""The MaterialX targets with an implementation, and how their code differs."""


@dataclass(frozen=True)
class LatentLayout:
    """The latent textures as the node reads them: ``groups`` RGBA files holding ``channels``
    channels, ``width`` x ``height`` texels at level 0 and ``levels`` MIP levels; ``shapes``: each
    level's (height, width), finest first (empty: halved and rounded up from level 0, as the
    export's EXRs and :func:`mtlx2neural.model.latent.level_shapes` size them). ``tiles``: the UDIM
    tiles of a UDIM material (sorted UDIM numbers; empty: one periodic pyramid over [0,1]^2), whose
    pyramids sit side by side in the atlas, tile k's block ``k`` block widths from the left
    (:func:`udim_atlas_width`), read at frac(uv) with clamp addressing."""

    channels: int
    groups: int
    width: int
    height: int
    levels: int
    shapes: tuple = ()
    tiles: tuple = ()

    def level_shapes(self) -> list[tuple[int, int]]:
        if self.shapes:
            return [tuple(s) for s in self.shapes]
        out = [(self.height, self.width)]
        for _ in range(self.levels - 1):
            h, w = out[-1]
            out.append((max(1, math.ceil(h / 2)), max(1, math.ceil(w / 2))))
        return out


def atlas_layout(shapes) -> tuple[list[tuple[int, int, int, int]], tuple[int, int]]:
    """Where each MIP level sits in the node's atlas texture: (rectangles (x, y, width, height) in
    texels, y counted from the atlas's top row, finest level first; the atlas's (height, width)).

    Level 0 fills the left, the coarser levels are stacked top-down in a column to its right, each
    at its own size, so that every texel of every level is stored once and bilinear taps wrap within
    their level's rectangle (the shader wraps; nothing bleeds between levels)."""
    shapes = [tuple(int(v) for v in s) for s in shapes]
    h0, w0 = shapes[0]
    rects, y = [(0, 0, w0, h0)], 0
    for h, w in shapes[1:]:
        rects.append((w0, y, w, h))
        y += h
    width = w0 + max((w for _, w in shapes[1:]), default=0)
    return rects, (max(h0, y), width)


def udim_atlas_width(layout: LatentLayout) -> int:
    """Width in texels of one tile's block in a UDIM material's atlas (one pyramid's atlas width)."""
    return atlas_layout(layout.level_shapes())[1][1]


def _udim_function(layout: LatentLayout, lang: str, p: str) -> str:
    """``<p>_udimSlot(texcoord)``: the atlas block of the UDIM tile under ``texcoord`` (-1: no trained tile)."""
    if not layout.tiles:
        return ""
    vec2 = LANGUAGES[lang][1]["vec2"]
    lines = ["// The trained UDIM tile under texcoord: its block in the atlas (slot k = the k-th tile of",
             f"// {', '.join(map(str, layout.tiles))}), -1 for a tile the material was not trained on.",
             f"int {p}_udimSlot({vec2} texcoord)", "{",
             "    int tu = int(floor(texcoord.x));", "    int tv = int(floor(texcoord.y));",
             "    if (tu < 0 || tu > 9 || tv < 0)", "        return -1;",
             "    int udim = 1001 + tu + 10 * tv;"]
    lines += [f"    if (udim == {t}) return {k};" for k, t in enumerate(layout.tiles)]
    lines += ["    return -1;", "}"]
    return "\n".join(lines)


def prefix(name: str) -> str:
    """The identifier part of a material's node names: :func:`.generate.identifier` with runs of
    underscores collapsed (GLSL reserves identifiers with two consecutive underscores)."""
    return re.sub(r"_+", "_", identifier(name))


def function_name(name: str) -> str:
    """The BSDF function the implementations define (``mx_neural_<ident>_bsdf``)."""
    return f"mx_neural_{prefix(name)}_bsdf"


def _check_finite(spec: NetworkSpec) -> None:
    arrays = [("the frame layer", spec.frame)] if spec.frame is not None else []
    for net, layers in (("decoder", spec.decoder), ("sampler", spec.sampler)):
        arrays += [(f"the {net}'s layer {i}", a) for i, layer in enumerate(layers) for a in (layer.weight, layer.bias)]
    for what, a in arrays:
        if not np.isfinite(a).all():
            raise InputError(f"{what} holds non-finite weights; the model cannot be written as a shader")


def _network_functions(spec: NetworkSpec, lang: str, p: str, P: str) -> str:
    t = LANGUAGES[lang][1]
    vec3, syntax = t["vec3"], LANGUAGES[lang][3]
    c, f = spec.latent_channels, spec.frames
    slots = max(f, 1)
    _check_finite(spec)
    out = ["// The frames of a latent code: frame k has n = normalize(v0 + (0,0,1)), t = normalize(v1 + (1,0,0)),",
           "// b = n x t (not orthogonalised), v = the frame layer times the latent, norms clamped at 1e-6.",
           f"{P}_Point {p}_point(float lat[{c}])", "{", f"    {P}_Point s;"]
    out += [f"    s.lat[{i}] = lat[{i}];" for i in range(c)]
    if f == 0:
        out += [f"    s.t[0] = {vec3}(1.0, 0.0, 0.0);", f"    s.b[0] = {vec3}(0.0, 1.0, 0.0);",
                f"    s.n[0] = {vec3}(0.0, 0.0, 1.0);"]
    lat = [f"lat[{i}]" for i in range(c)]
    for k in range(f):
        v = [affine(syntax, spec.frame[6 * k + j], 0.0, lat) for j in range(6)]
        out += [f"    s.n[{k}] = {p}_normalizeClamped({vec3}({v[0]}, {v[1]}, {v[2]} + 1.0), 1e-6);",
                f"    s.t[{k}] = {p}_normalizeClamped({vec3}({v[3]} + 1.0, {v[4]}, {v[5]}), 1e-6);",
                f"    s.b[{k}] = cross(s.n[{k}], s.t[{k}]);"]
    out += ["    return s;", "}", ""]

    cos = " * max(wo.z, 0.0)" if spec.analytic_cosine else ""
    x = [f"{d}{axis}{k}" for d in ("wi", "wo") for k in range(slots) for axis in "tbn"]
    lines = [f"    float {d}t{k} = dot({d}, s.t[{k}]), {d}b{k} = dot({d}, s.b[{k}]), {d}n{k} = dot({d}, s.n[{k}]);"
             for d in ("wi", "wo") for k in range(slots)]
    body, y = emit_mlp(describe("decoder", spec.decoder), Literal(f"{p}_relu", "d"), syntax,
                       x + [f"s.lat[{i}]" for i in range(c)])
    out += [f"// Decoder: [wi in each frame (t, b, n), wo likewise, latent] -> exp(min(y, 30) - 3){cos}.",
            f"{vec3} {p}_decode({P}_Point s, {vec3} wi, {vec3} wo)", "{", *lines, *body,
            f"    return {vec3}({p}_act({y[0]}), {p}_act({y[1]}), {p}_act({y[2]})){cos};", "}", ""]
    body, y = emit_mlp(describe("sampler", spec.sampler), Literal(f"{p}_relu", "q"), syntax,
                       ["wi.x", "wi.y", "wi.z"] + [f"s.lat[{i}]" for i in range(c)])
    out += ["// Sampler network: [wi, latent] -> the proxy's 9 raw parameters.",
            f"void {p}_sampler({P}_Point s, {vec3} wi, out float y[9])", "{", *body,
            *[f"    y[{i}] = {v};" for i, v in enumerate(y)], "}", ""]
    out += ["// Environment head: [wi in each frame (t, b, n), latent] -> the reflectance of the sharp lobe and",
            "// the sampler's specular and diffuse lobes, exp(min(y, 30) - 3) each (0 without an environment head).",
            f"void {p}_lobeReflectance({P}_Point s, {vec3} wi, out {vec3} cSharp, out {vec3} cSpec, out {vec3} cDiff)",
            "{"]
    if spec.environment:
        wi_lines = [f"    float wit{k} = dot(wi, s.t[{k}]), wib{k} = dot(wi, s.b[{k}]), win{k} = dot(wi, s.n[{k}]);"
                    for k in range(slots)]
        body, y = emit_mlp(describe("environment", spec.environment), Literal(f"{p}_relu", "e"), syntax,
                           [f"wi{axis}{k}" for k in range(slots) for axis in "tbn"] + [f"s.lat[{i}]" for i in range(c)])
        out += [*wi_lines, *body, f"    cSharp = {vec3}({', '.join(f'{p}_act({v})' for v in y[:3])});",
                f"    cSpec = {vec3}({', '.join(f'{p}_act({v})' for v in y[3:6])});",
                f"    cDiff = {vec3}({', '.join(f'{p}_act({v})' for v in y[6:])});"]
    else:
        out += [f"    cSharp = {vec3}(0.0);", f"    cSpec = {vec3}(0.0);", f"    cDiff = {vec3}(0.0);"]
    out.append("}")
    return "\n".join(out)


def _fetch_function(layout: LatentLayout, lang: str, p: str) -> str:
    t, sampler = LANGUAGES[lang][1], LANGUAGES[lang][2]
    params = ", ".join(f"{sampler} latent{g}" for g in range(layout.groups))
    lines = ["// The latent code at texcoord: one level of the pyramid (chosen with u), bilinear within it.",
             f"void {p}_fetch({params}, {t['vec2']} texcoord, float lod, float u, out float lat[{layout.channels}])",
             "{"]
    if layout.tiles:  # frac(uv) in the tile's block; the level argument carries the slot (levelRect)
        lines += [f"    {t['vec2']} st = mx_transform_uv(fract(texcoord), {t['vec2']}(1.0, 1.0), {t['vec2']}(0.0, 0.0));",
                  f"    int level = {p}_chooseLevel(lod, u) + {layout.levels} * max({p}_udimSlot(texcoord), 0);"]
    else:
        lines += [f"    {t['vec2']} st = mx_transform_uv(texcoord, {t['vec2']}(1.0, 1.0), {t['vec2']}(0.0, 0.0));",
                  f"    int level = {p}_chooseLevel(lod, u);"]
    for g in range(layout.groups):
        lines.append(f"    {t['vec4']} t{g} = {p}_bilinear(latent{g}, st, level);")
        for j in range(min(4, layout.channels - 4 * g)):
            lines.append(f"    lat[{4 * g + j}] = t{g}.{'xyzw'[j]};")
    lines.append("}")
    return "\n".join(lines)


def _level_rect_function(layout: LatentLayout, lang: str, p: str) -> str:
    ivec4 = "ivec4" if lang == "genglsl" else "int4"
    vec2 = LANGUAGES[lang][1]["vec2"]
    rects, (height, _) = atlas_layout(layout.level_shapes())
    lines = ["// The atlas rectangle (x, y, width, height) of MIP level `level`, in the texture's rows: counted",
             "// from the file's top row when the generator flips V (fileTextureVerticalFlip: texture row 0",
             "// holds the file's top row), else from its bottom row.",
             f"{ivec4} {p}_levelRect(int level)", "{"]
    if layout.tiles:  # level = MIP level + levels * UDIM slot: the slot's block, udim_atlas_width apart
        lines += [f"    int slot = level / {layout.levels};", f"    level -= slot * {layout.levels};"]
    lines.append(f"    {ivec4} r = {ivec4}({', '.join(map(str, rects[0]))});")
    for j, rect in enumerate(rects[1:], 1):
        lines.append(f"    if (level == {j}) r = {ivec4}({', '.join(map(str, rect))});")
    if layout.tiles:
        lines.append(f"    r.x += slot * {udim_atlas_width(layout)};")
    lines += [f"    if (mx_transform_uv({vec2}(0.0, 0.0), {vec2}(1.0, 1.0), {vec2}(0.0, 0.0)).y < 0.5)",
              f"        r.y = {height} - r.y - r.w;", "    return r;", "}"]
    return "\n".join(lines)


def node_source(spec: NetworkSpec, name: str, layout: LatentLayout, target: str, *, file: str, nodedef: str,
                version: str = "", source: str = "", seed: int = 0) -> str:
    """The text of the ``target`` (``genglsl`` or ``genslang``) implementation of ``nodedef`` for
    the material ``name`` whose networks are ``spec`` and latent textures ``layout``; ``file`` is
    the name the text is written under (for its header), ``source`` says where the weights came from;
    ``seed`` (0 to 2^27 - 1) offsets every hashed random stream of the sampled paths (two seeds: two
    independent renders, to measure noise)."""
    if target not in LANGUAGES:
        raise ValueError(f"unknown MaterialX target {target!r}: choose one of {', '.join(LANGUAGES)}")
    if layout.channels != spec.latent_channels or layout.groups != math.ceil(spec.latent_channels / 4):
        raise ValueError(f"{layout.groups} latent texture(s) of {layout.channels} channels do not fit networks "
                         f"reading {spec.latent_channels} latent channels")
    ident = prefix(name)
    p, P = f"nm_{ident}", f"NM_{ident}"
    shapes = {net: " -> ".join([str(layers[0].shape[1])] + [str(layer.shape[0]) for layer in layers])
              for net, layers in (("decoder", spec.decoder), ("sampler", spec.sampler))}
    nets = [f"// decoder {shapes['decoder']}, sampler {shapes['sampler']}, frame layer [{6 * spec.frames}, "
            f"{spec.latent_channels}]: FP32, every weight a literal in the code below"]
    activation = "exp(min(x, 30) - 3) * max(0, wo.z)" if spec.analytic_cosine else "exp(min(x, 30) - 3) (learned cosine)"
    subs = {
        "file": file, "nodedef": nodedef, "material": str(name), "version": version or "(unknown version)",
        "source": source or "a network spec", "p": p, "P": P, "function": function_name(name),
        "channels": layout.channels, "groups": layout.groups, "width": layout.width, "height": layout.height,
        "levels": layout.levels, "frames": spec.frames, "frame_slots": max(spec.frames, 1),
        "decoder_arch": "x".join(map(str, spec.decoder_hidden)) or "linear",
        "sampler_arch": "x".join(map(str, spec.sampler_hidden)) or "linear", "output_activation": activation,
        "network_shapes": "\n".join(nets), "network_functions": _network_functions(spec, target, p, P),
        "fetch_function": _fetch_function(layout, target, p),
        "udim_function": _udim_function(layout, target, p),
        "udim_guard": (f"if ({p}_udimSlot(texcoord) < 0)  // no trained UDIM tile here: black, as the Slang module\n"
                       f"        return;") if layout.tiles else "// one periodic latent pyramid: every uv reads it",
        "texel_x": "clamp(x, 0, r.z - 1)" if layout.tiles else "((x % r.z) + r.z) % r.z",
        "texel_y": "clamp(y, 0, r.w - 1)" if layout.tiles else "((y % r.w) + r.w) % r.w",
        "addressing": "clamped to its edges (a UDIM tile)" if layout.tiles else "wrapping periodically",
        "level_rect_function": _level_rect_function(layout, target, p),
        "level_rects": "atlas " + " x ".join(map(str, reversed(atlas_layout(layout.level_shapes())[1]))) + " texels"
        + (f" per UDIM tile, {len(layout.tiles)} tiles ({', '.join(map(str, layout.tiles))}) side by side"
           if layout.tiles else ""),
        "latent_params": ", ".join(f"{LANGUAGES[target][2]} latent{g}" for g in range(layout.groups)),
        "latent_args": ", ".join(f"latent{g}" for g in range(layout.groups)),
        "seed": int(seed), "has_environment_head": "true" if spec.environment else "false",
        "environment_head": "yes" if spec.environment else "no",
        "sharp_solid_angle": repr(float(SHARP_SOLID_ANGLE)),
        "sharp_live": "false" if spec.sharp_silent else "true",
        "sharp_note": ("The conversion silenced the sharp lobe (it carries nothing): no lookup."
                       if spec.sharp_silent else "The sharp lobe carries reflectance: one lookup."),
    }
    return Template(template(LANGUAGES[target][0])).substitute(subs)
