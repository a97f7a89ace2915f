"""The one MLP emitter (codegen/network_emitter.py): description, storages, per-target syntax.

The generated Slang module and MaterialX node are exercised end to end by test_codegen.py and
test_materialx_node.py (slangpy CPU runs, SPIR-V, MaterialX's GlslRenderer); these tests pin the
emitter's own contract.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from mtlx2neural.codegen.compile import CompileError, find_slangc, slangc
from mtlx2neural.codegen.network_emitter import (
    GLSL,
    HLSL,
    SLANG,
    Literal,
    Stream16,
    Stream32,
    describe,
    emit_mlp,
)
from mtlx2neural.codegen.spec import Layer


def _layers(shapes, seed=0) -> list[Layer]:
    rng = np.random.default_rng(seed)
    out = []
    for m, k in shapes:
        w = rng.normal(0.0, 0.7, (m, k)).astype(np.float32)
        w[0, 0] = 0.0  # a zero weight: left out of the literal form
        out.append(Layer(weight=w, bias=rng.normal(0.0, 0.3, m).astype(np.float32)))
    return out


def _reference(layers: list[Layer], x: np.ndarray) -> np.ndarray:
    """The MLP in float64 numpy: ReLU after every layer but the last."""
    for i, layer in enumerate(layers):
        x = layer.weight.astype(np.float64) @ x + layer.bias.astype(np.float64)
        if i < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return x


def test_describe_refuses_layers_that_do_not_chain():
    layers = _layers([(16, 5), (3, 8)])
    with pytest.raises(ValueError, match="layer 1 reads 8 inputs, but layer 0 writes 16"):
        describe("decoder", layers)
    net = describe("decoder", _layers([(16, 5), (16, 16), (3, 16)]))
    assert (net.inputs, net.outputs) == (5, 3) and [net.relu(i) for i in range(len(net.layers))] == [True, True, False]


@pytest.mark.parametrize("syntax", [SLANG, HLSL, GLSL], ids=lambda s: s.name)
def test_literal_form_computes_the_network(syntax):
    """The literal lines, read as Python (same expression grammar), give the numpy MLP. Tolerance
    1e-5 relative: each literal is the shortest decimal that rounds to the float32 weight, so it
    differs from it by at most half a float32 ulp (6e-8 relative), summed over <= 17 terms per neuron
    and three layers."""
    layers = _layers([(16, 5), (16, 16), (3, 16)], seed=1)
    names = [f"x{i}" for i in range(5)]
    lines, out = emit_mlp(describe("decoder", layers), Literal("relu", "d"), syntax, names)
    assert len(lines) == 16 + 16 + 3 and out == ["d2_0", "d2_1", "d2_2"]
    assert all(line.startswith("    float d") and line.endswith(";") for line in lines)
    assert not any(re.search(r"[+-] 0\.0 \* x0\b", line) for line in lines)  # the zero weight is left out
    x = np.random.default_rng(2).normal(size=5)
    scope = {"relu": lambda v: max(v, 0.0), **dict(zip(names, x))}
    for line in lines:
        name, expr = line.strip()[len("float "):-1].split(" = ", 1)
        scope[name] = eval(expr, {}, scope)  # noqa: S307 (our own generated arithmetic)
    got = np.array([scope[v] for v in out])
    np.testing.assert_allclose(got, _reference(layers, x), rtol=1e-5, atol=1e-6)


def test_library_forms_are_slang_only_and_read_the_weight_streams():
    net = describe("sampler", _layers([(32, 11), (9, 32)]))
    with pytest.raises(ValueError, match="GLSL has no Stream16 form"):
        emit_mlp(net, Stream16(), GLSL, "xh")
    lines, out = emit_mlp(net, Stream32("W()"), SLANG, "x")
    # layer 1 starts after layer 0's 32 neurons of (bias + 11 weights) in the FP32 access order
    assert lines == ["    float h0[32]; nmDense32<11, 32>(W(), 0, x, h0);", "    nmRelu32<32>(h0);",
                     f"    float h1[9]; nmDense32<32, 9>(W(), {32 * 12}, h0, h1);"] and out == "h1"
    lines, out = emit_mlp(net, Stream16("w"), SLANG, "xh")
    # FP16 pairs: 16 neuron pairs of (bias pair + 11 input pairs) before layer 1; 9 outputs -> 5 pairs
    assert lines[2] == f"    half2 p1[5]; nmDense16<32, 5>(w, {16 * 12}, h0, p1);" and out == "y"


@pytest.mark.skipif(find_slangc() is None, reason="slangc not found (pip install --no-deps slangtorch)")
def test_hlsl_literal_form_compiles_with_slangc(tmp_path):
    """The HLSL spelling of a network, in a compute shader, compiles as HLSL source to SPIR-V."""
    layers = _layers([(8, 3), (3, 8)], seed=3)
    lines, out = emit_mlp(describe("decoder", layers), Literal("nm_relu", "d"), HLSL, ["p.x", "p.y", "p.z"])
    src = tmp_path / "mlp.hlsl"
    src.write_text("\n".join([
        "RWStructuredBuffer<float3> result;",
        "float nm_relu(float v) { return max(v, 0.0); }",
        f"{HLSL.float3} decode({HLSL.float3} p)", "{", *lines, f"    return {HLSL.float3}({', '.join(out)});", "}",
        "[numthreads(1, 1, 1)]", "void main(uint3 id : SV_DispatchThreadID)",
        "{", "    result[id.x] = decode(float3(id));", "}"]))
    try:
        spv = slangc(src, "spirv", entry="main", stage="compute")
    except CompileError as exc:
        pytest.fail(f"the HLSL network does not compile: {exc}")
    assert spv[:4] == b"\x03\x02\x23\x07"  # SPIR-V magic number, little-endian
