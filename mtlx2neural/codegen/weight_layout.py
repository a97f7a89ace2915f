"""How a neural material's network weights are laid out for the shader paths that read them.

One definition per layout, shared by the generated code (:mod:`.network_emitter` emits code that
reads exactly these orders), the binaries the export writes (:mod:`.write`) and the emulations
(:mod:`.emulate`):

- **access-order streams** (:func:`stream32`, :func:`stream16`): per layer, per neuron (or neuron
  pair, for packed ``half2``), the bias then one weight per input, in the order an unrolled dense
  layer consumes them; :func:`fp16_blob` is the FP16 stream of every network as one binary;
- **matrices** (:func:`coopvec_blob`, :func:`coopmat_blob`): row-major FP16 matrices [out, in]
  zero-padded by :func:`padded_layers` and aligned for cooperative vectors and matrices.

Weight matrices are indexed [output, input], as torch's ``Linear.weight``.
"""

from __future__ import annotations

import numpy as np

from mtlx2neural.codegen.spec import Layer, NetworkSpec

MATRIX_ALIGN = 64  # bytes: cooperative-vector matrix offsets
BIAS_ALIGN = 16    # bytes: bias offsets and row strides
COOPMAT_TILE = 16  # M = N = K of the cooperative-matrix tiles (16x16x16 FP16)


def stream32(layers: list[Layer]) -> tuple[np.ndarray, list[int]]:
    """FP32 access order: per layer, per neuron (bias, weights); returns (values, layer bases)."""
    vals, bases, n = [], [], 0
    for l in layers:
        bases.append(n)
        block = np.concatenate([l.bias[:, None], l.weight], 1).astype(np.float32).ravel()
        vals.append(block)
        n += block.size
    return np.concatenate(vals), bases


def stream16(layers: list[Layer]) -> tuple[np.ndarray, list[int]]:
    """FP16 access order as [n, 2] pairs: per layer, per neuron pair (bias pair, then one pair
    per input); an odd output count is padded with a zero neuron. Returns (pairs, layer bases)."""
    vals, bases, n = [], [], 0
    for l in layers:
        m, k = l.shape
        m2 = (m + 1) // 2
        w = np.zeros((2 * m2, k + 1), np.float32)
        w[:m, 0], w[:m, 1:] = l.bias, l.weight
        pairs = w.reshape(m2, 2, k + 1).transpose(0, 2, 1).reshape(-1, 2)  # [(p, k), 2]
        bases.append(n)
        vals.append(pairs.astype(np.float16))
        n += pairs.shape[0]
    return np.concatenate(vals), bases


def fp16_blob(spec: NetworkSpec) -> tuple[bytes, dict[str, int]]:
    """The FP16 access-order streams of every network as one little-endian binary (for the
    ``*_FP16Buffer`` variant); returns (bytes, {network: byte offset}), offsets 16-aligned."""
    spec = spec.fp16()
    blob, offsets = bytearray(), {}
    for name, layers in spec.networks():
        blob += b"\0" * (-len(blob) % 16)
        offsets[name] = len(blob)
        blob += stream16(layers)[0].astype("<f2").tobytes()
    blob += b"\0" * (-len(blob) % 16)
    return bytes(blob), offsets


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def padded_layers(spec: NetworkSpec, row_multiple: int, col_multiple: int) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Every layer's FP16-rounded weight matrix and bias, zero-padded: the one definition of the
    padding of the matrix paths (:func:`coopvec_blob`, :func:`coopmat_blob`, the emulation).

    Returns {network: [(W [round_up(out, row_multiple), round_up(in, col_multiple)], bias
    [round_up(out, row_multiple)]), ...]} as float32 arrays holding FP16 values; W is indexed
    [output, input] as torch's ``Linear.weight``."""
    out = {}
    for name, layers in spec.fp16().networks():
        entries = []
        for l in layers:
            m, k = l.shape
            w = np.zeros((_round_up(m, row_multiple), _round_up(k, col_multiple)), np.float32)
            b = np.zeros(w.shape[0], np.float32)
            w[:m, :k], b[:m] = l.weight, l.bias
            entries.append((w, b))
        out[name] = entries
    return out


def _matrix_blob(spec: NetworkSpec, row_multiple: int, col_multiple: int) -> tuple[bytes, dict]:
    """Row-major FP16 matrices (padded by :func:`padded_layers`; matrices 64-byte aligned,
    biases 16-byte aligned) and the per-layer layout (see :func:`coopvec_blob`)."""
    blob, layout = bytearray(), {}
    shapes = {name: [l.shape for l in layers] for name, layers in spec.networks()}
    for name, entries in padded_layers(spec, row_multiple, col_multiple).items():
        out = []
        for (w, b), (m, k) in zip(entries, shapes[name]):
            blob += b"\0" * (-len(blob) % MATRIX_ALIGN)
            entry = {"matrix": len(blob), "shape": [m, k], "padded": list(w.shape), "row_stride": 2 * w.shape[1]}
            blob += w.astype("<f2").tobytes()
            blob += b"\0" * (-len(blob) % BIAS_ALIGN)
            entry["bias"] = len(blob)
            blob += b.astype("<f2").tobytes() if row_multiple > 1 else b[:m].astype("<f2").tobytes()
            out.append(entry)
        layout[name] = out
    blob += b"\0" * (-len(blob) % MATRIX_ALIGN)
    return bytes(blob), layout


def coopvec_blob(spec: NetworkSpec) -> tuple[bytes, dict]:
    """Row-major FP16 matrices and biases of every layer for the coherent path.

    Returns (bytes, layout) where layout[network] is a list of per-layer dicts with the byte
    ``matrix`` and ``bias`` offsets, ``shape`` [out, in], ``padded`` [out, in rounded up to 8]
    and ``row_stride`` in bytes (rows padded to 16 bytes, biases unpadded)."""
    return _matrix_blob(spec, 1, BIAS_ALIGN // 2)


def coopmat_blob(spec: NetworkSpec, tile: int = COOPMAT_TILE) -> tuple[bytes, dict]:
    """FP16 weights of every layer for the cooperative-matrix path (``NM_<name>_CoopMat``).

    Each layer's matrix W [out, in] is zero-padded to [round_up(out, tile), round_up(in,
    tile)] and stored **row-major** (one row per output neuron; row stride = padded inputs),
    which is the K x N operand B = W^T stored **column-major** with stride = padded inputs, as
    the shader loads it; matrices are 64-byte aligned. The bias follows, zero-padded to the
    padded output count, 16-byte aligned. Returns (bytes, layout) as :func:`coopvec_blob`
    (``row_stride`` in bytes = 2 x padded inputs)."""
    return _matrix_blob(spec, tile, tile)
