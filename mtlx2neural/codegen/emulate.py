"""NumPy emulation of the generated shader's FP16 arithmetic, operation by operation.

The generated FP16 path computes the network inputs (learned frames, projections) in float32
with FP16-rounded frame weights, converts them to half (clamped to +-65504), and evaluates each
layer as a chain of FMAs per neuron: the accumulator starts at the bias and takes the inputs in
order, rounding to half after every FMA; hidden layers apply ReLU (NaN -> 0, clamped to 65504);
the outputs go back to float32 for the activation (decoder: exp(min(x, 30) - 3); sampler: the
proxy parameterisation).

The emulation does the same in float32 arithmetic with a rounding to float16 after every FMA.
A float16 product is exact in float32 (11 + 11 significant bits), so each emulated FMA is
``half(float32(w * x) + acc)``: exactly what slangpy's CPU back end computes (it evaluates half
operations in float and rounds each result). GPUs fuse the FMA (one rounding), which differs
from this by at most one FP16 ulp per FMA in rare double-rounding cases.

:func:`mlp_coopmat` / :func:`decode_coopmat` follow the cooperative-matrix path (``NM_<name>_CoopMat``):
inputs and weights in half, padded to the tile with zeros (:func:`~.weight_layout.padded_layers`), one
``coopMatMulAdd`` per K tile whose products are summed exactly and rounded once to the accumulator
type (float32 or float16; hardware sums in an implementation-defined order and precision, the
spirv-run interpreter exactly like this), then bias and ReLU per element in the accumulator type.

``coopvec=True`` follows Slang's CPU emulation of cooperative vectors instead (measured:
products rounded to half, summed in half in input order, bias added last); GPUs accumulate in
an implementation-defined order and precision.
"""

from __future__ import annotations

import numpy as np

from mtlx2neural.codegen.spec import Layer, NetworkSpec
from mtlx2neural.codegen.weight_layout import COOPMAT_TILE, padded_layers

F16_MAX = np.float32(65504.0)


def _finite16(x: np.ndarray) -> np.ndarray:
    x = np.where(np.isnan(x), np.float32(0), x)
    return np.clip(x, -F16_MAX, F16_MAX).astype(np.float32)


def to_half(x: np.ndarray) -> np.ndarray:
    """float32 -> half (clamped, NaN -> 0), returned as float32 holding half values."""
    return _finite16(x).astype(np.float16).astype(np.float32)


def dense16(layer: Layer, x: np.ndarray) -> np.ndarray:
    """[N, K] half values -> [N, M] half values: per-FMA rounded chain from the bias."""
    w = layer.weight.astype(np.float16).astype(np.float32)
    acc = np.broadcast_to(layer.bias.astype(np.float16).astype(np.float32), (x.shape[0], w.shape[0])).copy()
    for k in range(w.shape[1]):
        with np.errstate(over="ignore", invalid="ignore"):
            acc = (x[:, k:k + 1] * w[None, :, k] + acc).astype(np.float16).astype(np.float32)
    return acc


def dense16_coopvec(layer: Layer, x: np.ndarray) -> np.ndarray:
    """The CPU emulation of ``coopVecMatMulAdd`` in Slang (measured): each product rounded to
    half, accumulated in half in input order from zero, then the bias added (rounded)."""
    w = layer.weight.astype(np.float16).astype(np.float32)
    b = layer.bias.astype(np.float16).astype(np.float32)
    acc = np.zeros((x.shape[0], w.shape[0]), np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(w.shape[1]):
            prod = (x[:, k:k + 1] * w[None, :, k]).astype(np.float16).astype(np.float32)
            acc = (acc + prod).astype(np.float16).astype(np.float32)
        return (acc + b).astype(np.float16).astype(np.float32)


def relu16(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0, np.minimum(x, F16_MAX), np.float32(0)).astype(np.float32)


def mlp16(layers: list[Layer], x: np.ndarray, coopvec: bool = False) -> np.ndarray:
    """The MLP on the FP16 path (``coopvec``: with the CPU CoopVec accumulation order)."""
    h = to_half(x)
    dense = dense16_coopvec if coopvec else dense16
    for i, l in enumerate(layers):
        h = dense(l, h)
        if i < len(layers) - 1:
            h = relu16(h)
    return _finite16(h)


def _normalize(v: np.ndarray, eps: float) -> np.ndarray:
    n = np.sqrt((v * v).sum(-1, keepdims=True, dtype=np.float32))
    return (v / np.maximum(n, np.float32(eps))).astype(np.float32)


def decoder_inputs(spec16: NetworkSpec, lat: np.ndarray, *ws: np.ndarray) -> np.ndarray:
    """The decoder's (or, with wi only, the albedo head's) float32 inputs."""
    lat = lat.astype(np.float32)
    if spec16.frames == 0:
        return np.concatenate([*ws, lat], 1).astype(np.float32)
    v = (lat @ spec16.frame.T.astype(np.float32)).reshape(-1, spec16.frames, 6)
    n = _normalize(v[..., 0:3] + np.float32([0, 0, 1]), 1e-6)
    t = _normalize(v[..., 3:6] + np.float32([1, 0, 0]), 1e-6)
    b = np.cross(n, t).astype(np.float32)
    parts = [np.stack([(w[:, None] * a).sum(-1) for a in (t, b, n)], -1).reshape(len(lat), -1) for w in ws]
    return np.concatenate([*parts, lat], 1).astype(np.float32)


def output_activation(y: np.ndarray) -> np.ndarray:
    c = np.where(y > -80, np.minimum(y, np.float32(30)), np.float32(-83))
    return np.exp(c - np.float32(3)).astype(np.float32)


def decode16(spec16: NetworkSpec, lat, wi, wo, coopvec: bool = False) -> np.ndarray:
    """f * cos [N, 3] of the FP16 path, without the horizon test (the cosine max(0, wo.z) multiplied
    in float32 when the spec's ``analytic_cosine``)."""
    y = output_activation(mlp16(spec16.decoder, decoder_inputs(spec16, lat, wi, wo), coopvec))
    return (y * np.maximum(wo[:, 2:3], 0).astype(np.float32)).astype(np.float32) if spec16.analytic_cosine else y


def albedo16(spec16: NetworkSpec, lat, wi, coopvec: bool = False) -> np.ndarray:
    """The albedo head's output [N, 3] on the FP16 path."""
    return output_activation(mlp16(spec16.albedo, decoder_inputs(spec16, lat, wi), coopvec))


def sampler_raw16(spec16: NetworkSpec, lat, wi, coopvec: bool = False) -> np.ndarray:
    """The sampler network's 9 raw outputs [N, 9] on the FP16 path."""
    return mlp16(spec16.sampler, np.concatenate([wi, lat], 1).astype(np.float32), coopvec)


def eval16(spec16: NetworkSpec, lat, wi, wo, coopvec: bool = False) -> np.ndarray:
    """eval() of the FP16 path: f * cos, 0 when wi or wo is at or below the horizon."""
    f = decode16(spec16, lat, wi, wo, coopvec)
    ok = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
    return np.where(ok, f, np.float32(0))


def mlp_coopmat(padded: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray, acc=np.float32,
                tile: int = COOPMAT_TILE) -> np.ndarray:
    """The MLP on the cooperative-matrix path: ``padded`` layers from :func:`padded_layers`
    (W [NP, KP], bias [NP], FP16 values), float32 inputs [N, K]; ``acc`` the accumulator type
    (np.float32 or np.float16). Returns the [N, NP] outputs as float32 (clamped, NaN -> 0)."""
    h = np.zeros((x.shape[0], padded[0][0].shape[1]), np.float32)
    h[:, :x.shape[1]] = to_half(x)
    with np.errstate(over="ignore", invalid="ignore"):
        for i, (w, b) in enumerate(padded):
            a = np.zeros((x.shape[0], w.shape[0]), acc)
            for k0 in range(0, w.shape[1], tile):
                part = h[:, k0:k0 + tile].astype(np.float64) @ w[:, k0:k0 + tile].T.astype(np.float64)
                a = (a.astype(np.float64) + part).astype(acc)
            v = (a + b.astype(acc)).astype(acc).astype(np.float32)
            if i < len(padded) - 1:
                h = np.where(v > 0, np.minimum(v, F16_MAX), np.float32(0)).astype(np.float16).astype(np.float32)
            else:
                return _finite16(v)
    raise ValueError("no layers")


def decode_coopmat(spec16: NetworkSpec, lat, wi, wo, acc=np.float32) -> np.ndarray:
    """f * cos [N, 3] of the cooperative-matrix path (as :func:`decode16`, without the horizon test)."""
    padded = padded_layers(spec16, COOPMAT_TILE, COOPMAT_TILE)["decoder"]
    y = output_activation(mlp_coopmat(padded, decoder_inputs(spec16, lat, wi, wo), acc)[:, :3])
    return (y * np.maximum(wo[:, 2:3], 0).astype(np.float32)).astype(np.float32) if spec16.analytic_cosine else y


def sampler_raw_coopmat(spec16: NetworkSpec, lat, wi, acc=np.float32) -> np.ndarray:
    """The sampler network's 9 raw outputs [N, 9] on the cooperative-matrix path."""
    padded = padded_layers(spec16, COOPMAT_TILE, COOPMAT_TILE)["sampler"]
    return mlp_coopmat(padded, np.concatenate([wi, lat], 1).astype(np.float32), acc)[:, :9]
