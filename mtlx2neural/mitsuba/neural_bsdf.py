"""The ``mtlx_neural`` Mitsuba BSDF: a converted material read from its exported neural layer and
evaluated in Dr.Jit (:mod:`mtlx2neural.mitsuba.neural_model`).

Plugin properties:

- ``filename`` (string, required): the exported neural layer (``*_neural.usda``), resolved by Mitsuba's
  file resolver (relative to the scene file's folder when loaded from XML). Read with
  :func:`~mtlx2neural.export.load.load_neural`, i.e. from the exported files (FP16 latents and weights),
  never a checkpoint;
- ``material`` (string, optional when the layer holds one neural material): its prim path, prim name or
  MaterialX name;
- ``lod`` (float, default :data:`DEFAULT_LOD` = 0): the level of detail, in latent-pyramid levels, used
  where the shading point has no ray differentials (``si.duv_dx`` and ``si.duv_dy`` both zero, which is
  what Mitsuba's integrators give unless they compute uv partials). 0 is the finest level: without a
  footprint there is nothing to prefilter for, and it is the torch model's default (a ShadingPoint
  without ``lod``), which the reference, point-sampling its graph, also matches best.

With ray differentials the level of detail is log2 of the larger of the two uv footprints in level-0
texels, ``log2(max(|duv_dx * (W, H)|, |duv_dy * (W, H)|))``, clamped to the pyramid; fractional levels
are a deterministic blend of the two nearest levels' latents (``neural_model``'s docstring says why it
differs from torch's random level choice there, and agrees at integer levels).

Conventions (those of :mod:`mtlx2neural.mitsuba` and :mod:`mtlx2neural.contract`): ``si.wi`` is the
direction to the viewer in the local shading frame (the contract's ``wi``), ``wo`` the direction to the
light (the contract's ``wo``); ``eval`` returns f(wi, wo) * cos(theta_o) in linear RGB (the cosine
included), ``pdf`` the solid-angle density (1/sr) of ``sample``, whose weight is eval / pdf. The latents
are looked up at ``si.uv`` (the project's uv: (0, 0) the bottom-left corner of the texture, periodic).
Where ``wi`` or ``wo`` is at or below the horizon (cos <= 0) ``eval`` and ``pdf`` are 0; a sampled ``wo``
at or below the horizon gets weight 0 and pdf 0, so a sample's pdf equals ``pdf`` of its direction.

One component, flags GlossyReflection | DiffuseReflection | FrontSide (plus SpatiallyVarying for a
textured material): the decoder is one BRDF, not a sum of lobes that could be evaluated apart. The
component is skipped (zeros) when the context excludes both of its types. ``sample`` reports the proxy
lobe that drew the direction as ``sampled_type`` (GlossyReflection for the specular lobe,
DiffuseReflection for the cosine one), ``sampled_component`` 0 and ``eta`` 1. ``sample1`` (the
component choice) is unused: the proxy picks its lobe with ``sample2.x`` and reuses it, as the torch
model does with ``u[:, 0]``, so ``sample(ctx, si, s1, s2)`` equals the torch ``sample(wi, u=s2)``.
The transport mode is ignored (the learned BRDF is used as it is for importance transport too).

Not supported: UDIM materials (several latent pyramids addressed by uv tile) raise :class:`InputError`
naming the material at load; emission and opacity maps beside the latents are not part of a BSDF
(Mitsuba would take them as an area emitter and a mask) and are ignored here.

Models are read and copied into Dr.Jit once per (layer file and its modification time, material,
array type) and cached for the process (:func:`cached_model`): Mitsuba's chi-square adapter builds a
plugin for every call.
"""

from __future__ import annotations

from pathlib import Path

import drjit as dr
import mitsuba as mi

from mtlx2neural.errors import InputError
from mtlx2neural.export.load import load_neural
from mtlx2neural.mitsuba.neural_model import NeuralModel

DEFAULT_LOD = 0.0
"""The ``lod`` property's default: the finest latent level (module docstring)."""

_MODELS: dict = {}


def cached_model(path, material: str | None, Float) -> tuple[NeuralModel, dict]:
    """(the Dr.Jit model, the torch model's ``describe()``) of ``material`` in the neural layer ``path``,
    for arrays of type ``Float``; read once per (file, modification time, material, type).
    :class:`InputError` for a UDIM material (not supported) and whatever ``load_neural`` raises."""
    path = Path(path).resolve()
    if not path.is_file():
        raise InputError(f"{path}: no such file; give mtlx_neural the .usda that `mtlx2neural ASSET` wrote")
    key = (str(path), material, path.stat().st_mtime_ns, Float)
    hit = _MODELS.get(key)
    if hit is None:
        torch_model = load_neural(path, material)
        info = torch_model.describe()
        if info.get("udim_tiles"):
            raise InputError(f"{path}: {info['material']} is a UDIM material (tiles {info['udim_tiles']}); "
                             f"the mtlx_neural Mitsuba plugin does not read UDIM latents")
        try:
            model = NeuralModel.from_torch(torch_model, Float)
        except ValueError as exc:
            raise InputError(f"{path}: {info['material']}: {exc}") from None
        hit = _MODELS[key] = (model, info)
    return hit


def _to_tuple(v):
    return (v.x, v.y, v.z)


class NeuralBSDF(mi.BSDF):
    """The ``mtlx_neural`` plugin: an exported neural material as a Mitsuba BSDF (module docstring)."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        filename = props.get("filename", None)
        if not filename:
            raise InputError("mtlx_neural needs a 'filename': the exported neural layer (*_neural.usda)")
        self.filename = str(mi.file_resolver().resolve(str(filename)))
        material = props.get("material", None)
        self.material = str(material) if material else None
        self.lod = float(props.get("lod", DEFAULT_LOD))
        self.model, self.info = cached_model(self.filename, self.material, mi.Float)
        flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        if self.model.latents.constant is None:
            flags = flags | mi.BSDFFlags.SpatiallyVarying
        self.m_components = [flags]
        self.m_flags = flags

    # ------------------------------------------------------------------ where: latents at si

    def _lod(self, si):
        """Level of detail per lane: from the uv partials where present, else the ``lod`` property."""
        h, w = self.model.latents.resolution
        dx = dr.sqrt(dr.square(si.duv_dx.x * w) + dr.square(si.duv_dx.y * h))
        dy = dr.sqrt(dr.square(si.duv_dy.x * w) + dr.square(si.duv_dy.y * h))
        footprint = dr.maximum(dx, dy)
        lod = dr.select(dr.isfinite(footprint) & (footprint > 0), dr.log2(footprint), self.lod)
        return dr.select(dr.isfinite(lod), lod, self.lod)

    def _latent(self, si):
        return self.model.latent(si.uv.x, si.uv.y, self._lod(si))

    def _enabled(self, ctx) -> bool:
        return (ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)
                or ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0))

    # ------------------------------------------------------------------ the BSDF interface

    def eval(self, ctx, si, wo, active=True):
        """f(wi, wo) * cos(theta_o), linear RGB (Color3f); 0 at or below the horizon."""
        if not self._enabled(ctx):
            return mi.Color3f(0.0)
        ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        f = self.model.eval(self._latent(si), _to_tuple(si.wi), _to_tuple(wo))
        return dr.select(ok, mi.Color3f(*f), 0.0)

    def pdf(self, ctx, si, wo, active=True):
        """Solid-angle density (1/sr, no cosine) of :meth:`sample` at ``wo``; 0 at or below the horizon."""
        if not self._enabled(ctx):
            return mi.Float(0.0)
        ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        p = self.model.pdf(_to_tuple(si.wi), _to_tuple(wo), self._latent(si))
        return dr.select(ok, p, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        """(:meth:`eval`, :meth:`pdf`) sharing one latent lookup."""
        if not self._enabled(ctx):
            return mi.Color3f(0.0), mi.Float(0.0)
        ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        lat = self._latent(si)
        wi, wo_t = _to_tuple(si.wi), _to_tuple(wo)
        f = self.model.eval(lat, wi, wo_t)
        p = self.model.pdf(wi, wo_t, lat)
        return dr.select(ok, mi.Color3f(*f), 0.0), dr.select(ok, p, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        """(BSDFSample3f, weight = eval / pdf, the cosine included) drawn from the learned proxy with
        ``sample2``; weight 0 and pdf 0 where wi or the sampled wo is at or below the horizon."""
        bs = dr.zeros(mi.BSDFSample3f)
        if not self._enabled(ctx):
            return bs, mi.Color3f(0.0)
        wi = _to_tuple(si.wi)
        lat = self._latent(si)
        wo, pdf, spec = self.model.sample(wi, lat, sample2.x, sample2.y)
        above = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (wo[2] > 0)
        pdf = dr.select(above, pdf, 0.0)
        ok = above & (pdf > 0)
        f = mi.Color3f(*self.model.eval(lat, wi, wo))
        bs.wo = mi.Vector3f(*wo)
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_type = dr.select(spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        bs.sampled_component = mi.UInt32(0)
        return bs, dr.select(ok, f / dr.maximum(pdf, 1e-12), 0.0)

    def to_string(self):
        lat = self.model.latents
        return (f"NeuralBSDF[\n  filename = \"{self.filename}\",\n  material = \"{self.info['material']}\",\n"
                f"  lod = {self.lod},\n  resolution = {list(lat.resolution)},\n  levels = {lat.num_levels},\n"
                f"  decoder_hidden = {self.info['decoder_hidden']},\n  frames = {self.model.frames}\n]")
