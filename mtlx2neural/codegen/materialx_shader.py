"""GLSL and Slang source of a neural material's MaterialX BSDF node, from its networks.

:func:`node_source` fills ``codegen/templates/neural_bsdf.glsl.in`` (MaterialX target
``genglsl``) or ``neural_bsdf.slang.in`` (``genslang``) with the same :class:`NetworkSpec` that
:mod:`.generate` turns into the Slang modules: the frame layer, the decoder MLP and the sampler
MLP, in FP32 with every weight baked in as a constant (the per-neuron "bias, weights" order of
:func:`.generate.stream32`), evaluated by loops over those constant arrays. The hand-written
parts of the templates (proxy sampling and pdf, the level choice, the BSDF function) follow the
Slang runtime (``codegen/slang/NeuralMaterial.slang``) and the torch model line by line.

The function follows MaterialX's closure contract (docs/notes/materialx-custom-bsdf.md):
``void <function>(ClosureData closureData, float weight, <one sampler per latent texture>,
vec2 texcoord, vec3 normal, vec3 tangent, int env_samples, inout BSDF bsdf)`` -- the nodedef's
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

from mtlx2neural.codegen.generate import _f32, identifier, stream32
from mtlx2neural.codegen.paths import template
from mtlx2neural.codegen.spec import NetworkSpec
from mtlx2neural.errors import InputError

LANGUAGES = {
    # target -> (template, type names, sampler type, how a constant float array is declared)
    "genglsl": ("neural_bsdf.glsl.in", {"vec2": "vec2", "vec3": "vec3", "vec4": "vec4"}, "sampler2D",
                "const float {name}[{n}] = float[{n}](\n    {body}\n);"),
    "genslang": ("neural_bsdf.slang.in", {"vec2": "float2", "vec3": "float3", "vec4": "float4"},
                 "SamplerTexture2D", "static const float {name}[{n}] = {{\n    {body}\n}};"),
}
"""The MaterialX targets with an implementation, and how their code differs."""


@dataclass(frozen=True)
class LatentLayout:
    """The latent textures as the node reads them: ``groups`` RGBA files holding ``channels``
    channels, ``width`` x ``height`` texels at level 0 and ``levels`` MIP levels."""

    channels: int
    groups: int
    width: int
    height: int
    levels: int


def prefix(name: str) -> str:
    """The identifier part of a material's node names: :func:`.generate.identifier` with runs of
    underscores collapsed (GLSL reserves identifiers with two consecutive underscores)."""
    return re.sub(r"_+", "_", identifier(name))


def function_name(name: str) -> str:
    """The BSDF function the implementations define (``mx_neural_<ident>_bsdf``)."""
    return f"mx_neural_{prefix(name)}_bsdf"


def _array(lang: str, name: str, values: np.ndarray, per_line: int = 8) -> str:
    values = np.asarray(values, np.float32).ravel()
    if not np.isfinite(values).all():
        raise InputError(f"the networks hold {int((~np.isfinite(values)).sum())} non-finite weight(s) in {name}; "
                         f"the model cannot be written as a shader")
    items = [_f32(v) for v in values] or ["0.0"]
    body = ",\n    ".join(", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line))
    return LANGUAGES[lang][3].format(name=name, n=len(items), body=body)


def _mlp(layers, array: str, x: str, out: str, p: str) -> list[str]:
    """Lines computing the float array ``out`` from ``x`` with ReLU hidden layers and a linear
    last layer, reading weights from ``array`` in the per-neuron (bias, weights) order."""
    _, bases = stream32(layers)
    lines, cur = [], x
    for i, (layer, base) in enumerate(zip(layers, bases)):
        m, k = layer.shape
        last = i == len(layers) - 1
        dst = out if last else f"h{i}"
        if not last:
            lines.append(f"    float {dst}[{m}];")
        act = "s" if last else f"{p}_relu(s)"
        lines += [f"    for (int o = 0; o < {m}; o++)", "    {",
                  f"        int r = {base} + o * {k + 1};",
                  f"        float s = {array}[r];",
                  f"        for (int i = 0; i < {k}; i++)",
                  f"            s += {array}[r + 1 + i] * {cur}[i];",
                  f"        {dst}[o] = {act};", "    }"]
        cur = dst
    return lines


def _network_functions(spec: NetworkSpec, lang: str, p: str, P: str) -> str:
    t = LANGUAGES[lang][1]
    vec3 = t["vec3"]
    c, f = spec.latent_channels, spec.frames
    slots = max(f, 1)
    out = ["// The frames of a latent code: frame k has n = normalize(v0 + (0,0,1)), t = normalize(v1 + (1,0,0)),",
           "// b = n x t (not orthogonalised), v = the frame layer times the latent, norms clamped at 1e-6.",
           f"{P}_Point {p}_point(float lat[{c}])", "{", f"    {P}_Point s;",
           f"    for (int i = 0; i < {c}; i++)", "        s.lat[i] = lat[i];"]
    if f == 0:
        out += [f"    s.t[0] = {vec3}(1.0, 0.0, 0.0);", f"    s.b[0] = {vec3}(0.0, 1.0, 0.0);",
                f"    s.n[0] = {vec3}(0.0, 0.0, 1.0);"]
    else:
        out += [f"    for (int k = 0; k < {f}; k++)", "    {", "        float v[6];",
                "        for (int j = 0; j < 6; j++)", "        {", "            float a = 0.0;",
                f"            for (int i = 0; i < {c}; i++)",
                f"                a += {P}_FRAME[(6 * k + j) * {c} + i] * lat[i];", "            v[j] = a;", "        }",
                f"        s.n[k] = {p}_normalizeClamped({vec3}(v[0], v[1], v[2] + 1.0), 1e-6);",
                f"        s.t[k] = {p}_normalizeClamped({vec3}(v[3] + 1.0, v[4], v[5]), 1e-6);",
                "        s.b[k] = cross(s.n[k], s.t[k]);", "    }"]
    out += ["    return s;", "}", ""]

    k_dec = 6 * slots + c
    cos = " * max(wo.z, 0.0)" if spec.analytic_cosine else ""
    out += [f"// Decoder: [wi in each frame (t, b, n), wo likewise, latent] -> exp(min(y, 30) - 3){cos}.",
            f"{vec3} {p}_decode({P}_Point s, {vec3} wi, {vec3} wo)", "{", f"    float x[{k_dec}];",
            f"    for (int k = 0; k < {slots}; k++)", "    {",
            "        x[3 * k] = dot(wi, s.t[k]); x[3 * k + 1] = dot(wi, s.b[k]); x[3 * k + 2] = dot(wi, s.n[k]);",
            f"        x[{3 * slots} + 3 * k] = dot(wo, s.t[k]); x[{3 * slots} + 3 * k + 1] = dot(wo, s.b[k]); "
            f"x[{3 * slots} + 3 * k + 2] = dot(wo, s.n[k]);", "    }",
            f"    for (int i = 0; i < {c}; i++)", f"        x[{6 * slots} + i] = s.lat[i];", "    float y[3];",
            *_mlp(spec.decoder, f"{P}_DEC", "x", "y", p),
            f"    return {vec3}({p}_act(y[0]), {p}_act(y[1]), {p}_act(y[2])){cos};", "}", ""]

    out += ["// Sampler network: [wi, latent] -> the proxy's 9 raw parameters.",
            f"void {p}_sampler({P}_Point s, {vec3} wi, out float y[9])", "{", f"    float x[{3 + c}];",
            "    x[0] = wi.x; x[1] = wi.y; x[2] = wi.z;", f"    for (int i = 0; i < {c}; i++)",
            "        x[3 + i] = s.lat[i];", *_mlp(spec.sampler, f"{P}_SMP", "x", "y", p), "}"]
    return "\n".join(out)


def _fetch_function(layout: LatentLayout, lang: str, p: str) -> str:
    t, sampler = LANGUAGES[lang][1], LANGUAGES[lang][2]
    params = ", ".join(f"{sampler} latent{g}" for g in range(layout.groups))
    lines = ["// The latent code at texcoord: one level of the pyramid (chosen with u), bilinear within it.",
             f"void {p}_fetch({params}, {t['vec2']} texcoord, float lod, float u, out float lat[{layout.channels}])",
             "{", f"    {t['vec2']} st = mx_transform_uv(texcoord, {t['vec2']}(1.0, 1.0), {t['vec2']}(0.0, 0.0));",
             f"    int level = {p}_chooseLevel(lod, u);"]
    for g in range(layout.groups):
        lines.append(f"    {t['vec4']} t{g} = {p}_bilinear(latent{g}, st, level);")
        for j in range(min(4, layout.channels - 4 * g)):
            lines.append(f"    lat[{4 * g + j}] = t{g}.{'xyzw'[j]};")
    lines.append("}")
    return "\n".join(lines)


def node_source(spec: NetworkSpec, name: str, layout: LatentLayout, target: str, *, file: str, nodedef: str,
                version: str = "", source: str = "") -> str:
    """The text of the ``target`` (``genglsl`` or ``genslang``) implementation of ``nodedef`` for
    the material ``name`` whose networks are ``spec`` and latent textures ``layout``; ``file`` is
    the name the text is written under (for its header), ``source`` says where the weights came from."""
    if target not in LANGUAGES:
        raise ValueError(f"unknown MaterialX target {target!r}: choose one of {', '.join(LANGUAGES)}")
    if layout.channels != spec.latent_channels or layout.groups != math.ceil(spec.latent_channels / 4):
        raise ValueError(f"{layout.groups} latent texture(s) of {layout.channels} channels do not fit networks "
                         f"reading {spec.latent_channels} latent channels")
    ident = prefix(name)
    p, P = f"nm_{ident}", f"NM_{ident}"
    frames = spec.frame if spec.frame is not None else np.zeros(1, np.float32)
    arrays = [f"// frame layer [{6 * spec.frames}, {spec.latent_channels}], row-major, no bias",
              _array(target, f"{P}_FRAME", frames)]
    for tag, net, layers in (("DEC", "decoder", spec.decoder), ("SMP", "sampler", spec.sampler)):
        shapes = " -> ".join([str(layers[0].shape[1])] + [str(l.shape[0]) for l in layers])
        arrays += [f"// {net} {shapes}, FP32, per neuron: bias, then its weights",
                   _array(target, f"{P}_{tag}", stream32(layers)[0])]
    activation = "exp(min(x, 30) - 3) * max(0, wo.z)" if spec.analytic_cosine else "exp(min(x, 30) - 3) (learned cosine)"
    subs = {
        "file": file, "nodedef": nodedef, "material": str(name), "version": version or "(unknown version)",
        "source": source or "a network spec", "p": p, "P": P, "function": function_name(name),
        "channels": layout.channels, "groups": layout.groups, "width": layout.width, "height": layout.height,
        "levels": layout.levels, "frames": spec.frames, "frame_slots": max(spec.frames, 1),
        "decoder_arch": "x".join(map(str, spec.decoder_hidden)) or "linear",
        "sampler_arch": "x".join(map(str, spec.sampler_hidden)) or "linear", "output_activation": activation,
        "arrays": "\n".join(arrays), "network_functions": _network_functions(spec, target, p, P),
        "fetch_function": _fetch_function(layout, target, p),
        "latent_params": ", ".join(f"{LANGUAGES[target][2]} latent{g}" for g in range(layout.groups)),
        "latent_args": ", ".join(f"latent{g}" for g in range(layout.groups)),
    }
    return Template(template(LANGUAGES[target][0])).substitute(subs)
