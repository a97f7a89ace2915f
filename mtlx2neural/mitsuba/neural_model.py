"""The neural material in Dr.Jit: the twin of :class:`~mtlx2neural.model.neural_material.NeuralMaterial`
for Dr.Jit arrays (latent pyramid lookup, learned frames + decoder MLP, sampler MLP + the analytic
two-lobe proxy's sample and pdf), built once from a torch model and then evaluated without torch.

Conventions, the torch model's (:mod:`mtlx2neural.contract`): directions are unit vectors in the local
shading frame (z the normal, x the tangent), given as tuples ``(x, y, z)`` of Dr.Jit ``Float`` arrays;
``wi`` points to the viewer, ``wo`` to the light. :meth:`NeuralModel.eval` returns f(wi, wo) * cos
(the cosine included) in linear RGB, :meth:`NeuralModel.pdf` a solid-angle density (1/sr). Nothing
here tests the horizon or normalises its input directions: the caller (the Mitsuba plugin) does, as
``NeuralMaterial`` does around the same networks.

Arithmetic is float32 throughout. The exported weights and latents are FP16 values, which float32
holds exactly; the MLPs run as Dr.Jit cooperative vectors (:mod:`drjit.nn`) on float32 tensors. Measured
against torch's float32 on a 19-64-64-64-3 network over 262k random inputs: 1e-5 absolute on outputs up
to 36 (rounding order); FP16 cooperative vectors were off by 0.09 there, and the decoder's exp output
turns that into a 9% error, so float32 it is (FP16 was not faster on the LLVM backend either: 1.5 s
against 1.0 s for that test, compilation included).

Latents: all levels of the pyramid sit end to end in one ``Float`` buffer, texel-major (channel fastest),
and are read by a manual bilinear gather (rather than one Dr.Jit texture per level: one buffer serves
every level, chosen per lane) with periodic addressing, the conventions of
:func:`~mtlx2neural.imaging.grid_lookup.bilinear_periodic` (uv (0, 0) the bottom-left corner, row 0 of a
level at v = 1, texel centres at half-integers), in the same float32 operations, so it agrees with torch
to rounding. Level selection differs on purpose: torch picks floor(lod) or floor(lod) + 1 at random
(probability frac(lod)); here the two levels' latent codes are blended linearly by frac(lod) (a
trilinear lookup), which is deterministic, so that ``eval``, ``pdf`` and ``sample`` of one shading point
see the same material (a random choice per call would make ``sample`` and ``pdf`` disagree). At integer
lod both are the same single level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np
from drjit import nn

from mtlx2neural.formats.weights import OUTPUT_OFFSET
from mtlx2neural.model.proxy import PDF_MIN_COS

OUTPUT_CLAMP = 30.0
"""The decoder's raw outputs are clamped to at most this before exp (``BrdfDecoder.activate``; the
manifest's ``output_clamp``)."""


# ----------------------------------------------------------------------------- small vector helpers


def dot(a, b):
    """Dot product of two 3-tuples of arrays."""
    return dr.fma(a[0], b[0], dr.fma(a[1], b[1], a[2] * b[2]))


def cross(a, b):
    """Cross product a x b of two 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def normalize(a, floor: float):
    """``a / max(|a|, floor)`` (torch's ``a / a.norm().clamp_min(floor)``)."""
    n = dr.maximum(dr.sqrt(dot(a, a)), floor)
    return (a[0] / n, a[1] / n, a[2] / n)


# ----------------------------------------------------------------------------- MLP


class MLP:
    """A fully connected ReLU network (torch's :func:`~mtlx2neural.model.mlp.mlp`) as a packed
    :mod:`drjit.nn` cooperative-vector module in float32. ``layers``: ``[(W [out, in], b [out]), ...]``
    as numpy arrays, ReLU between consecutive layers, none after the last; ``Float`` the Dr.Jit array
    type of the inputs (its tensor type holds the weights)."""

    def __init__(self, layers, Float):
        self.Float = Float
        tensor = dr.tensor_t(Float)
        self.in_features = int(layers[0][0].shape[1])
        self.out_features = int(layers[-1][0].shape[0])
        modules = []
        for i, (w, _) in enumerate(layers):
            modules.append(nn.Linear(int(w.shape[1]), int(w.shape[0])))
            if i + 1 < len(layers):
                modules.append(nn.ReLU())
        net = nn.Sequential(*modules).alloc(tensor, self.in_features)
        for i, (w, b) in enumerate(layers):
            net.layers[2 * i].weights = tensor(np.ascontiguousarray(w, dtype=np.float32))
            net.layers[2 * i].bias = tensor(np.ascontiguousarray(b, dtype=np.float32))
        self.net = nn.pack(net, layout="inference")

    def __call__(self, inputs) -> list:
        """``in_features`` Float arrays (or Python floats, broadcast) -> ``out_features`` Float arrays."""
        if len(inputs) != self.in_features:
            raise ValueError(f"the MLP takes {self.in_features} inputs, got {len(inputs)}")
        out = self.net(nn.CoopVec(*[self.Float(x) for x in inputs]))
        return [self.Float(v) for v in out]


def torch_layers(seq) -> list:
    """``[(W, b), ...]`` float32 numpy arrays of the ``nn.Linear`` layers of a torch ``nn.Sequential``."""
    out = []
    for m in seq:
        if hasattr(m, "weight"):
            out.append((m.weight.detach().cpu().float().numpy(), m.bias.detach().cpu().float().numpy()))
    return out


# ----------------------------------------------------------------------------- latent pyramid


class LatentLookup:
    """The latent pyramid as one Dr.Jit buffer. ``levels``: ``[C, H, W]`` float32 numpy arrays, finest
    first (as :class:`~mtlx2neural.model.latent.LatentPyramid` reads them); ``Float`` the array type.
    Non-UDIM pyramids only (periodic addressing)."""

    def __init__(self, levels, Float):
        self.Float = Float
        self.UInt32 = dr.uint32_array_t(Float)
        self.Int32 = dr.int32_array_t(Float)
        self.channels = int(levels[0].shape[0])
        self.shapes = [(int(lv.shape[1]), int(lv.shape[2])) for lv in levels]
        self.num_levels = len(levels)
        # A uniform material (one level of one texel) is a constant code: no lookup, as in torch.
        self.constant = None
        if self.num_levels == 1 and self.shapes[0] == (1, 1):
            self.constant = [float(v) for v in np.asarray(levels[0], dtype=np.float32).reshape(-1)]
        offsets, total = [], 0
        for h, w in self.shapes:
            offsets.append(total)
            total += h * w
        flat = np.concatenate([np.ascontiguousarray(np.asarray(lv, dtype=np.float32).transpose(1, 2, 0)).ravel()
                               for lv in levels])
        self.buffer = Float(flat)  # texel-major: channel c of texel t of level k at (offset_k + t) * C + c
        self.offsets = self.UInt32(offsets)
        self.heights = self.UInt32([h for h, _ in self.shapes])
        self.widths = self.UInt32([w for _, w in self.shapes])

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W) of level 0."""
        return self.shapes[0]

    def fetch(self, u, v, level) -> list:
        """Bilinear latents (``channels`` Float arrays) at finite uv ``(u, v)`` from the integer ``level``
        (UInt32 per lane, 0 = finest, within range), periodic addressing: ``bilinear_periodic``."""
        if self.constant is not None:
            return [self.Float(c) for c in self.constant]
        Float, Int32, UInt32 = self.Float, self.Int32, self.UInt32
        w_i = Int32(dr.gather(UInt32, self.widths, level))
        h_i = Int32(dr.gather(UInt32, self.heights, level))
        base = dr.gather(UInt32, self.offsets, level)
        x = (u - dr.floor(u)) * Float(w_i) - 0.5
        y = (1.0 - (v - dr.floor(v))) * Float(h_i) - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        ix0, iy0 = Int32(x0), Int32(y0)  # in [-1, W-1] and [-1, H-1]
        ix0 = dr.select(ix0 < 0, ix0 + w_i, ix0)
        iy0 = dr.select(iy0 < 0, iy0 + h_i, iy0)
        ix1 = dr.select(ix0 + 1 >= w_i, ix0 + 1 - w_i, ix0 + 1)
        iy1 = dr.select(iy0 + 1 >= h_i, iy0 + 1 - h_i, iy0 + 1)
        taps = ((ix0, iy0, (1 - fx) * (1 - fy)), (ix1, iy0, fx * (1 - fy)),
                (ix0, iy1, (1 - fx) * fy), (ix1, iy1, fx * fy))
        c = self.channels
        out = [Float(0.0)] * c
        for ix, iy, wgt in taps:  # the order of torch's sum, for the same rounding
            idx = (base + UInt32(iy * w_i + ix)) * c
            for k in range(c):
                out[k] = out[k] + dr.gather(Float, self.buffer, idx + k) * wgt
        return out

    def lookup(self, u, v, lod) -> list:
        """Latents at uv ``(u, v)`` and level of detail ``lod`` (Float, in levels, 0 = finest; clamped to
        the pyramid; a non-finite uv or lod reads 0 there): levels floor(lod) and floor(lod) + 1 blended linearly by frac(lod) (module
        docstring); exactly level ``lod`` at integer lod."""
        if self.constant is not None:
            return self.fetch(u, v, None)
        # Non-finite input (inactive lanes may hold anything) reads uv 0 and the finest level, so that
        # every gather stays inside the buffer.
        u = dr.select(dr.isfinite(u), u, 0.0)
        v = dr.select(dr.isfinite(v), v, 0.0)
        lod = dr.select(dr.isfinite(lod), lod, 0.0)
        lod = dr.clip(self.Float(lod), 0.0, float(self.num_levels - 1))
        k0 = dr.floor(lod)
        t = lod - k0
        l0 = self.UInt32(k0)
        l1 = dr.minimum(l0 + 1, self.num_levels - 1)
        a = self.fetch(u, v, l0)
        if self.num_levels == 1:
            return a
        b = self.fetch(u, v, l1)
        return [dr.select(t > 0, dr.fma(t, bk - ak, ak), ak) for ak, bk in zip(a, b)]


# ----------------------------------------------------------------------------- the analytic proxy


@dataclass
class ProxyParams:
    """The proxy's parameters per lane (:class:`mtlx2neural.model.proxy.ProxyParams`), Float arrays."""

    alpha_x: object
    alpha_y: object
    rho: object
    slope_spec: tuple  # (x, y) mean microfacet slope of the specular lobe
    slope_diff: tuple  # (x, y) tilt of the diffuse lobe
    w_spec: object     # probability of the specular lobe

    @staticmethod
    def from_network(raw) -> ProxyParams:
        """The sampler's 9 raw outputs -> parameters, with the paper's activations (``from_network``)."""
        soft = [r / dr.sqrt(1.0 + r * r) for r in raw]
        grow = [r * dr.sqrt(1.0 + r * r) for r in raw]
        # softmax over (raw[7], raw[8]), first entry; the larger logit subtracted as torch does
        m = dr.maximum(raw[7], raw[8])
        e7, e8 = dr.exp(raw[7] - m), dr.exp(raw[8] - m)
        return ProxyParams(1e-4 + 0.5 * (1.0 + soft[0]), 1e-4 + 0.5 * (1.0 + soft[1]), soft[2],
                           (grow[3], grow[4]), (grow[5], grow[6]), e7 / (e7 + e8))


def _axis(sx, sy):
    """The unit normal (-sx, -sy, 1) / |.| of a slope."""
    return normalize((-sx, -sy, 1.0), 0.0)


def _tangents(n):
    """Frame (s, t) around ``n`` built from the x axis (``proxy._tangents``)."""
    s = (1.0 - n[0] * n[0], -n[1] * n[0], -n[2] * n[0])
    s = normalize(s, 1e-12)
    return s, cross(n, s)


def sample_diffuse(p: ProxyParams, u0, u1):
    """Cosine-distributed direction about the tilted axis (``proxy.sample_diffuse``)."""
    phi = 2.0 * math.pi * u0
    r = dr.sqrt(dr.clip(u1, 0.0, 1.0))
    sin_phi, cos_phi = dr.sincos(phi)
    local = (r * cos_phi, r * sin_phi, dr.sqrt(dr.maximum(1.0 - u1, 0.0)))
    n = _axis(*p.slope_diff)
    s, t = _tangents(n)
    return tuple(local[0] * s[i] + local[1] * t[i] + local[2] * n[i] for i in range(3))


def sample_specular(wi, p: ProxyParams, u0, u1):
    """``wi`` reflected about a normal from the non-centred GGX slope density (``proxy.sample_specular``)."""
    uu = dr.clip(u0, 0.0, 1.0 - 1e-7)
    r = dr.sqrt(uu / (1.0 - uu))
    sin_phi, cos_phi = dr.sincos(2.0 * math.pi * u1)
    x, y = r * cos_phi, r * sin_phi
    c = dr.sqrt(dr.maximum(1.0 - p.rho * p.rho, 1e-8))
    sx = p.alpha_x * x + p.slope_spec[0]
    sy = p.alpha_y * (p.rho * x + c * y) + p.slope_spec[1]
    h = _axis(sx, sy)
    d = 2.0 * dot(wi, h)
    return tuple(d * h[i] - wi[i] for i in range(3))


def proxy_sample(wi, p: ProxyParams, u0, u1):
    """(wo, specular): the proxy's direction (unit, or NaN/zero where its numerics failed; the caller
    treats a non-finite or zero ``wo`` as below the horizon) from uniform ``(u0, u1)``, and whether the
    specular lobe drew it. ``u0`` picks the lobe and is rescaled for reuse (``proxy.sample``)."""
    ws = p.w_spec
    spec = u0 < ws
    us0 = dr.clip(u0 / dr.maximum(ws, 1e-12), 0.0, 1.0)
    ud0 = dr.clip((u0 - ws) / dr.maximum(1.0 - ws, 1e-12), 0.0, 1.0)
    u1c = dr.clip(u1, 0.0, 1.0)
    a = sample_specular(wi, p, us0, u1c)
    b = sample_diffuse(p, ud0, u1c)
    wo = tuple(dr.select(spec, a[i], b[i]) for i in range(3))
    return normalize(wo, 1e-12), spec


def pdf_specular(wi, wo, p: ProxyParams):
    """Solid-angle density of the specular lobe (``proxy.pdf_specular``)."""
    h = normalize(tuple(wi[i] + wo[i] for i in range(3)), 1e-12)
    h = scale(h, dr.select(h[2] < 0, -1.0, 1.0))
    ok = h[2] > PDF_MIN_COS
    cos_t = dr.maximum(h[2], PDF_MIN_COS)
    sx = -h[0] / cos_t - p.slope_spec[0]
    sy = -h[1] / cos_t - p.slope_spec[1]
    c = dr.sqrt(dr.maximum(1.0 - p.rho * p.rho, 1e-8))
    ax, ay = p.alpha_x, p.alpha_y
    norm = 1.0 / (ax * ay * c)
    x = sx / ax
    y = (ax * sy - p.rho * ay * sx) * norm
    r2 = x * x + y * y
    p22 = norm / (math.pi * dr.square(1.0 + r2))
    pdf_h = p22 / (cos_t * cos_t * cos_t)
    jac = 4.0 * dr.maximum(dr.abs(dot(wi, h)), 1e-12)
    return dr.select(ok, pdf_h / jac, 0.0)


def pdf_diffuse(wo, p: ProxyParams):
    """Solid-angle density of the tilted cosine lobe (``proxy.pdf_diffuse``)."""
    return dr.maximum(dot(wo, _axis(*p.slope_diff)) / math.pi, 0.0)


def proxy_pdf(wi, wo, p: ProxyParams):
    """The mixture's solid-angle density over the whole sphere (``proxy.pdf``); no horizon test."""
    ws = p.w_spec
    return ws * pdf_specular(wi, wo, p) + (1.0 - ws) * pdf_diffuse(wo, p)


UNIT_TOLERANCE = 16 * 2.0 ** -23
"""|length^2 - 1| up to which a float32 vector counts as unit (the contract's ``UNIT_ULPS`` ulps)."""


def finite_direction(w):
    """What ``NeuralMaterial`` makes of a sampled direction: non-finite components set to 0
    (``nan_to_num``), then :func:`~mtlx2neural.contract.normalize_directions`: a zero vector becomes
    (0, 0, -1), below the horizon; a unit vector (to ``UNIT_TOLERANCE``) passes unchanged; others are
    divided by their largest absolute component, then by their length."""
    w = tuple(dr.select(dr.isfinite(c), c, 0.0) for c in w)
    m = dr.maximum(dr.abs(w[0]), dr.maximum(dr.abs(w[1]), dr.abs(w[2])))
    zero = m == 0
    unit = dr.abs(dot(w, w) - 1.0) <= UNIT_TOLERANCE
    v = tuple(c / dr.select(zero, 1.0, m) for c in w)
    v = normalize(v, 1.0)
    below = (0.0, 0.0, -1.0)
    return tuple(dr.select(unit, w[i], dr.select(zero, below[i], v[i])) for i in range(3))


# ----------------------------------------------------------------------------- the whole model


class NeuralModel:
    """The Dr.Jit twin of a torch :class:`~mtlx2neural.model.neural_material.NeuralMaterial` (its
    exported parts: latents, frame layer, decoder and sampler MLPs; the encoder trains only and the
    optional albedo head is a training aid). Build with :meth:`from_torch`."""

    def __init__(self, latents: LatentLookup, frame_weight, decoder: MLP, sampler: MLP, analytic_cosine: bool,
                 Float):
        self.Float = Float
        self.latents = latents
        self.frame_weight = None if frame_weight is None else np.asarray(frame_weight, dtype=np.float32)
        self.frames = 0 if frame_weight is None else int(self.frame_weight.shape[0]) // 6
        self.decoder = decoder
        self.sampler = sampler
        self.analytic_cosine = bool(analytic_cosine)

    @staticmethod
    def from_torch(model, Float) -> NeuralModel:
        """Copy ``model``'s tensors (a NeuralMaterial, e.g. from ``load_neural``) into Dr.Jit arrays of
        type ``Float``. ``ValueError`` for what the twin does not implement: UDIM latents, the ablations
        (an extra latent layer, an isotropic sampler)."""
        lat = model.latents
        if lat.tiles is not None:
            raise ValueError(f"UDIM latents (tiles {lat.tile_list}) are not supported by the Dr.Jit model")
        dec = model.decoder
        if dec.latent_layer is not None or getattr(model.sampler, "isotropic", False):
            raise ValueError("an ablation model (extra latent layer or isotropic sampler) is not supported")
        levels = [lat.level(k).detach().cpu().float().numpy() for k in range(lat.num_levels)]
        frame = None if dec.frame_layer is None else dec.frame_layer.weight.detach().cpu().float().numpy()
        return NeuralModel(LatentLookup(levels, Float), frame, MLP(torch_layers(dec.net), Float),
                           MLP(torch_layers(model.sampler.net), Float), dec.analytic_cosine, Float)

    @property
    def latent_dim(self) -> int:
        return self.latents.channels

    def latent(self, u, v, lod) -> list:
        """Latent code (``latent_dim`` Float arrays) at uv ``(u, v)``, level of detail ``lod``."""
        return self.latents.lookup(u, v, lod)

    def shading_frames(self, lat) -> list:
        """[(t, b, n), ...] per learned frame from the latent (``BrdfDecoder.shading_frames``)."""
        w = self.frame_weight
        frames = []
        for f in range(self.frames):
            v = [sum((float(w[6 * f + j, i]) * lat[i] for i in range(1, len(lat))), float(w[6 * f + j, 0]) * lat[0])
                 for j in range(6)]
            n = normalize((v[0], v[1], v[2] + 1.0), 1e-6)
            t = normalize((v[3] + 1.0, v[4], v[5]), 1e-6)
            frames.append((t, cross(n, t), n))
        return frames

    def _project(self, w, frames) -> list:
        if not frames:  # frames = 0: the local direction as it is
            return list(w)
        return [dot(w, axis) for frame in frames for axis in frame]

    def eval(self, lat, wi, wo):
        """f(wi, wo) * max(0, wo.z): an (r, g, b) tuple of Float, linear RGB, the cosine included (exactly
        with ``analytic_cosine``, learned otherwise). No horizon test on ``wi``."""
        frames = self.shading_frames(lat) if self.frames else []
        raw = self.decoder(self._project(wi, frames) + self._project(wo, frames) + list(lat))
        out = [dr.exp(dr.minimum(x, OUTPUT_CLAMP) - OUTPUT_OFFSET) for x in raw]
        if self.analytic_cosine:
            cos = dr.maximum(wo[2], 0.0)
            out = [x * cos for x in out]
        return tuple(out)

    def proxy(self, wi, lat) -> ProxyParams:
        """The sampler network's proxy parameters at ``wi`` for the latent ``lat``."""
        return ProxyParams.from_network(self.sampler(list(wi) + list(lat)))

    def sample(self, wi, lat, u0, u1):
        """(wo, pdf, specular) from the proxy: ``wo`` unit, or (0, 0, -1) where the proxy's numerics failed
        (:func:`finite_direction`); ``pdf`` the proxy's density at ``wo`` (1/sr), no
        horizon test; ``specular`` whether the specular lobe drew it."""
        p = self.proxy(wi, lat)
        wo, spec = proxy_sample(wi, p, u0, u1)
        wo = finite_direction(wo)
        return wo, proxy_pdf(wi, wo, p), spec

    def pdf(self, wi, wo, lat):
        """The proxy's density (1/sr) at ``wo``; no horizon test."""
        return proxy_pdf(wi, wo, self.proxy(wi, lat))
