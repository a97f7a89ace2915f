"""One emitter for the MLPs of every shader target.

In the style of MaterialX ShaderGen: a network is described once, as data, and a per-target syntax
layer spells it. Everything that writes a neural material's networks as shader code (the Slang
module of :mod:`.generate`, the MaterialX node of :mod:`.materialx_shader`, and through ``slangc``
the HLSL and SPIR-V engine files of :mod:`.engine`) goes through :func:`emit_mlp`.

The three parts:

- :class:`Network`: the MLP itself, a chain of layers ``y = W x + b`` (W indexed [output, input]
  as torch's ``Linear.weight``), ReLU after every layer but the last, which is linear (the output activation belongs to the caller: the decoder's ``exp``, the sampler's proxy
  parameters);
- a **weight storage**, saying where the weights are and at which precision the layers run:

  ========================  =========  =======================================================
  storage                   precision  weights
  ========================  =========  =======================================================
  :class:`Literal`          FP32       every weight an immediate in the code (zeros left out)
  :class:`Stream32`         FP32       an access-order array (:func:`.weight_layout.stream32`)
  :class:`Stream16`         FP16       packed ``half2`` pairs (:func:`.weight_layout.stream16`)
  :class:`CoopVecMatrices`  FP16       row-major matrices in a buffer (``coopvec_blob`` layout)
  :class:`CoopMatTiles`     FP16       padded matrix tiles in a buffer (``coopmat_blob`` layout)
  ========================  =========  =======================================================

- a :class:`Syntax` per target language (:data:`SLANG`, :data:`HLSL`, :data:`GLSL`): type names and
  which storages it can express. The storages other than :class:`Literal` call the dense-layer
  templates of the Slang runtime (``codegen/slang/NeuralLayers.slang``: ``nmDense32``,
  ``nmDense16``, ``nmCoopDense``, ...), so they exist in Slang (and in HLSL and SPIR-V through
  ``slangc``); GLSL has the literal form, which needs no library.

:func:`emit_mlp` returns the statement lines (four-space indented) and the output: the name of the
output array for the array storages, the list of output scalar expressions for :class:`Literal`.
A new target adds a :class:`Syntax`; a new weight layout adds a storage and its case in
:func:`emit_mlp`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mtlx2neural.codegen.spec import Layer
from mtlx2neural.codegen.weight_layout import stream16, stream32

# ------------------------------------------------------------------------------------------
# The network
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Network:
    """An MLP as every target sees it: ``name`` (``decoder``, ``sampler``, ``albedo``) and its
    :class:`.spec.Layer` list, input first: ``y = weight @ x + bias`` (weight [outputs, inputs]), ReLU
    after every layer but the last (:meth:`relu`)."""

    name: str
    layers: tuple[Layer, ...]

    @property
    def inputs(self) -> int:
        return self.layers[0].shape[1]

    @property
    def outputs(self) -> int:
        return self.layers[-1].shape[0]

    def relu(self, i: int) -> bool:
        """Whether layer ``i`` is followed by a ReLU (every one but the last)."""
        return i < len(self.layers) - 1


def describe(name: str, layers: list[Layer]) -> Network:
    """The :class:`Network` of the spec's ``layers``. Raises ValueError when the layers do not chain (a
    layer's inputs differ from the previous one's outputs)."""
    if not layers:
        raise ValueError(f"the {name} network has no layers")
    for i in range(1, len(layers)):
        if layers[i].shape[1] != layers[i - 1].shape[0]:
            raise ValueError(f"the {name} network's layer {i} reads {layers[i].shape[1]} inputs, but layer "
                             f"{i - 1} writes {layers[i - 1].shape[0]}")
    return Network(name, tuple(layers))


# ------------------------------------------------------------------------------------------
# Weight storages
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Literal:
    """FP32, every weight an immediate: nothing is indexed at run time (what Mesa's llvmpipe needs,
    see :mod:`.materialx_shader`). Hidden activations are ``relu(expr)`` scalars named
    ``<stem><layer>_<neuron>``."""

    relu: str
    """Name of the ReLU function the target's code defines (``nm_<material>_relu``)."""
    stem: str
    """Stem of the per-neuron variable names (``d`` for the decoder, ``q`` for the sampler)."""


@dataclass(frozen=True)
class Stream32:
    """FP32 dense layers reading an access-order array through an ``INMWeights32`` object."""

    weights: str
    """Expression giving the weights object, e.g. ``NM_Mat_Dec32()``."""


@dataclass(frozen=True)
class Stream16:
    """FP16 dense layers on packed ``half2`` pairs, reading an ``INMWeights16`` object; the last layer's
    output is unpacked to a float array ``y``."""

    weights: str = "w"
    """Expression giving the weights object."""


@dataclass(frozen=True)
class CoopVecMatrices:
    """FP16 cooperative-vector products on row-major matrices in a ``ByteAddressBuffer``; the result is
    converted to a float array ``y``."""

    entries: list
    """Per layer: the ``coopvec_blob`` layout entry (``matrix`` and ``bias`` byte offsets)."""
    buffer: str = "wb"
    base: str = "base"
    """Expression of the network's byte offset in the buffer."""


@dataclass(frozen=True)
class CoopMatTiles:
    """FP16 cooperative-matrix layers on a tile ``t`` whose inputs the caller stored; the last layer
    writes a float array ``y``."""

    entries: list
    """Per layer: the ``coopmat_blob`` layout entry (``shape``, ``padded``, ``matrix``, ``bias``)."""
    prefix: str
    """The material's prefix: the tile helpers are ``<prefix>_cmLayer`` / ``_cmHidden`` / ``_cmOutput``."""
    buffer: str = "wb"
    base: str = "base"


# ------------------------------------------------------------------------------------------
# Per-target syntax
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Syntax:
    """How one shading language spells the network code."""

    name: str
    float3: str
    half: str
    half2: str
    storages: tuple[type, ...]
    """The storages this target can express (the others need the Slang runtime's layer templates)."""

    def float_literal(self, x: float) -> str:
        """The shortest decimal that reads back as the float32 ``x`` (``1.0``, ``-0.25``, ``3e-05``)."""
        text = str(np.float32(x))
        return text if any(ch in text for ch in ".e") else text + ".0"

    def check(self, storage) -> None:
        if not isinstance(storage, self.storages):
            raise ValueError(f"{self.name} has no {type(storage).__name__} form of a network: it needs the "
                             "Slang runtime's layer templates (use Literal, or generate Slang and compile it)")


_ALL = (Literal, Stream32, Stream16, CoopVecMatrices, CoopMatTiles)
SLANG = Syntax("Slang", "float3", "half", "half2", _ALL)
HLSL = Syntax("HLSL", "float3", "half", "half2", (Literal,))
"""HLSL written directly (the other storages reach HLSL through ``slangc``: :mod:`.compile`)."""
GLSL = Syntax("GLSL", "vec3", "float16_t", "f16vec2", (Literal,))
SYNTAXES = {"slang": SLANG, "hlsl": HLSL, "glsl": GLSL}


# ------------------------------------------------------------------------------------------
# The emitter
# ------------------------------------------------------------------------------------------

def emit_mlp(net: Network, storage, syntax: Syntax, x):
    """Statement lines of ``net`` on the input ``x`` in ``syntax`` with the weights in ``storage``.

    ``x``: the input array's name (array storages) or the list of ``net.inputs`` scalar expressions
    (:class:`Literal`). Returns ``(lines, output)``: ``output`` is the output array's name, or for
    :class:`Literal` the list of output scalar expressions."""
    syntax.check(storage)
    if isinstance(storage, Literal):
        return _literal(net, storage, syntax, list(x))
    if isinstance(storage, Stream32):
        return _stream32(net, storage, x)
    if isinstance(storage, Stream16):
        return _stream16(net, storage, syntax, x)
    if isinstance(storage, CoopVecMatrices):
        return _coopvec(net, storage, syntax, x)
    return _coopmat(net, storage)


def affine(syntax: Syntax, weights: np.ndarray, bias: float, inputs: list[str]) -> str:
    """One neuron without activation as a literal expression: ``bias + sum(w * input)`` with the
    weights as literals (zero weights left out)."""
    terms = [syntax.float_literal(bias)]
    for w, x in zip(weights, inputs):
        if w != 0:
            lit = syntax.float_literal(w)
            terms.append(f"- {lit[1:]} * {x}" if lit.startswith("-") else f"+ {lit} * {x}")
    return " ".join(terms)


def _literal(net: Network, s: Literal, syntax: Syntax, x: list[str]):
    if len(x) != net.inputs:
        raise ValueError(f"the {net.name} network reads {net.inputs} inputs, given {len(x)}")
    lines, cur = [], x
    for i, layer in enumerate(net.layers):
        out = []
        for o in range(layer.shape[0]):
            var = f"{s.stem}{i}_{o}"
            expr = affine(syntax, layer.weight[o], float(layer.bias[o]), cur)
            lines.append(f"    float {var} = {f'{s.relu}({expr})' if net.relu(i) else expr};")
            out.append(var)
        cur = out
    return lines, cur


def _stream32(net: Network, s: Stream32, x: str):
    lines, cur = [], x
    for i, (layer, base) in enumerate(zip(net.layers, stream32(list(net.layers))[1])):
        m, k = layer.shape
        lines.append(f"    float h{i}[{m}]; nmDense32<{k}, {m}>({s.weights}, {base}, {cur}, h{i});")
        if net.relu(i):
            lines.append(f"    nmRelu32<{m}>(h{i});")
        cur = f"h{i}"
    return lines, cur


def _stream16(net: Network, s: Stream16, syntax: Syntax, x: str):
    lines, cur = [], x
    for i, (layer, base) in enumerate(zip(net.layers, stream16(list(net.layers))[1])):
        m, k = layer.shape
        m2 = (m + 1) // 2
        lines.append(f"    {syntax.half2} p{i}[{m2}]; nmDense16<{k}, {m2}>({s.weights}, {base}, {cur}, p{i});")
        if net.relu(i):
            lines.append(f"    {syntax.half} h{i}[{2 * m2}]; nmReluUnpack16<{m2}, {2 * m2}>(p{i}, h{i});")
            cur = f"h{i}"
        else:
            lines.append(f"    float y[{m}]; nmUnpackOutput16<{m2}, {m}>(p{i}, y);")
    return lines, "y"


def _coopvec(net: Network, s: CoopVecMatrices, syntax: Syntax, x: str):
    lines, cur = [], x
    for i, (layer, e) in enumerate(zip(net.layers, s.entries)):
        m, k = layer.shape
        call = f"nmCoopDense<{k}, {m}>({cur}, {s.buffer}, {s.base} + {e['matrix']}u, {s.base} + {e['bias']}u)"
        if net.relu(i):
            call = f"nmCoopRelu<{m}>({call})"
        lines.append(f"    CoopVec<{syntax.half}, {m}> v{i} = {call};")
        cur = f"v{i}"
    lines.append(f"    float y[{net.outputs}]; nmCoopToFloat<{net.outputs}>({cur}, y);")
    return lines, "y"


def _coopmat(net: Network, s: CoopMatTiles):
    lines, p = [], s.prefix
    for i, e in enumerate(s.entries):
        (m, _), (mp, kp) = e["shape"], e["padded"]
        lines.append(f"    {p}_cmLayer<{kp}, {mp}>(t, {s.buffer}, {s.base} + {e['matrix']}u);")
        if net.relu(i):
            lines.append(f"    {p}_cmHidden<{mp}>(t, {s.buffer}, {s.base} + {e['bias']}u);")
        else:
            lines.append(f"    float y[{m}]; {p}_cmOutput<{m}>(t, {s.buffer}, {s.base} + {e['bias']}u, y);")
    return lines, "y"
