"""The Mitsuba BSDF plugin ``mtlx_reference``: the compiled MaterialX reference BRDF
(:class:`mtlx2neural.reference.ReferenceMaterial`, torch) inside Mitsuba 3.

Properties (``mi.load_dict({"type": "mtlx_reference", ...})``):

- ``filename`` (string, required): a ``.mtlx`` file, a USD stage, or a neural layer ``*_neural.usda``
  this tool wrote; for a layer, the reference of the *original* input its record names
  (``LayerRecord.source``) is loaded (a layer of mtlx2neural 0.2 records none: an error naming it).
- ``material`` (string, optional): a USD material prim path or prim name, or a MaterialX
  ``surfacematerial`` name (:func:`mtlx2neural.scene.find_material`); may be omitted when the asset (or
  the layer's record) holds exactly one.
- ``flip_v`` (bool, default false): read ``si.uv`` as (u, 1 - v). The plugin passes Mitsuba's ``si.uv``
  to the reference as the contract's uv (MaterialX's convention, (0, 0) an image's bottom-left); a scene
  whose meshes carry uvs in the other convention (top-left origin) sets it.
- ``pdf_scale`` (float, default 1): **a test hook**: multiplies every density the plugin reports
  (``pdf``, ``eval_pdf``'s pdf, ``sample``'s ``bs.pdf``), not the sampling nor the weights: a deliberately
  wrong pdf for the chi-square test's control. Leave it at 1.

The conversion's settings: when a conversion of the material left its record (``summary.json`` in the
material folder, found through the layer's record, or beside an original asset where ``mtlx2neural
ASSET`` writes it), the reference is built as that conversion built it: its ``--frame``/``--fps`` (the
instant ``time``/``frame`` nodes fold to) and its ``--allow-missing-textures``. Without a record: frame 1
at 24 fps, and a missing texture is an error. References are cached per (resolved ``filename``, its
modification time, ``material`` as given) for the life of the process, since Mitsuba instantiates a
plugin per ``load_dict`` (the chi-square adapter does so on every call); a record written later is not
seen by a cached reference.

Mapping onto :mod:`mtlx2neural.contract`: Mitsuba's ``si.wi`` (towards the viewer, local shading frame:
z the shading normal, x ``si.sh_frame.s``) is the contract's ``wi``; the ``wo`` of ``eval``/``pdf`` and
the sampled ``bs.wo`` (towards the light) are its ``wo``; ``eval`` includes the cosine factor in both
(MaterialX's cosine: about the material's own normal where it has a normal map); ``sample``'s weight is
eval / pdf and ``pdf`` is per steradian, without cosine. ``si.uv`` is the contract's uv (see ``flip_v``).
Mitsuba's two random inputs map onto the reference's ``u`` [N, 3] as ``(sample2.x, sample2.y,
sample1)``: ``sample1`` chooses the lobe (the reference's third column), ``sample2`` the direction within
it. Below the horizon (``wi.z <= 0`` or ``wo.z <= 0``) eval and pdf are 0 and a sample has weight 0 and
pdf 0 (the reference's own rule); lanes that are inactive or carry NaN/Inf directions give 0 as well
(the reference raises on non-finite input, which a renderer must not trigger), a non-finite uv reads
(0.5, 0.5). The BSDF is one-sided (``FrontSide``) and reflects only. Radiance transport only: MaterialX's
layered closures are not reciprocal, and in ``TransportMode.Importance`` (light tracing) ``si.wi`` is
still read as the direction to the viewer.

Flags (:func:`material_flags`): ``DiffuseReflection`` when the compiled program keeps a diffuse closure
(Oren-Nayar, Burley, subsurface), ``GlossyReflection`` when it keeps a microfacet or sheen closure,
``FrontSide`` always; one component with their union. No delta lobes: the reference has none (its GGX
roughness stays finite). ``bs.sampled_type`` is ``GlossyReflection`` when the material has a glossy
lobe, else ``DiffuseReflection``: the reference does not say which lobe a sample came from.

The torch round trip (:func:`reference_eval` etc., ``@dr.wrap(source="drjit", target="torch")``): every
call evaluates its Dr.Jit inputs, hands them to torch as zero-copy DLPack views (Dr.Jit's ``[3, N]``
layout, copied into contiguous ``[N, 3]`` rows, the contract's), runs the reference eagerly in torch (the
material graph, textures included, once per call) under ``torch.no_grad``, and imports the results back
zero-copy. Measured on 2^16 lanes, one torch thread, CPU: the bridge alone (an identity function) costs
about 1.3 ms; the plugin's ``eval`` took 23.6 / 33.2 / 75.7 ms against 19.9 / 30.0 / 72.6 ms for the
torch reference called directly (Plastic / CarPaint / GlazedCeramic), ``sample`` 58 / 90 / 143 ms against
56 / 87 / 140 ms: a few milliseconds per call, the torch reference dominates. Each call is one
synchronisation point: the plugin cannot run inside a *symbolic* Dr.Jit loop or virtual call, so a
renderer using it must set ``dr.JitFlag.SymbolicLoops`` and ``dr.JitFlag.SymbolicCalls`` to False
(evaluated mode: each bounce a kernel launch, then the torch call). No gradients flow through the
plugin (torch runs without autograd; ``traverse`` exposes nothing); compiling the reference to Dr.Jit
itself, which would remove the round trip and the synchronisation, is out of scope here.

``emission(uv)`` and ``opacity(uv)`` (not part of Mitsuba's BSDF interface; the scene builder handles
emission and cut-outs) return the reference's emitted radiance (``mi.Color3f``, linear RGB, no cosine) and
opacity (``mi.Float`` in [0, 1]) at ``uv``, or None when the material emits nothing / is opaque.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.graph.ops import Application
from mtlx2neural.material_record import read_record_or_none
from mtlx2neural.pipeline.layout import material_folder, names_entry
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.reference.loading import application_of, load_reference
from mtlx2neural.report.views import conversion_outputs, neural_layer_record
from mtlx2neural.scene import find_material
from mtlx2neural.scene.dependencies import canonical

DIFFUSE_CLOSURES = frozenset({"oren_nayar_diffuse_bsdf", "burley_diffuse_bsdf", "subsurface_bsdf"})
"""pbrlib closures whose reflection Mitsuba calls diffuse."""
GLOSSY_CLOSURES = frozenset({"conductor_bsdf", "dielectric_bsdf", "generalized_schlick_bsdf", "sheen_bsdf"})
"""pbrlib closures whose reflection Mitsuba calls glossy (microfacet and sheen lobes)."""
# translucent_bsdf transmits only: the reference (reflection only) never shows it, so it adds no flag.

ALL_COMPONENTS = 0xFFFFFFFF  # BSDFContext.component when every component is asked for (uint32 -1)


# ----------------------------------------------------------------------------- which reference


@dataclass(frozen=True)
class ReferenceSource:
    """What the plugin loads: the original asset, the material in it and the conversion's settings."""

    path: Path
    """The asset the reference is read from (for a neural layer, the input its record names)."""
    material: str
    """The material's name as :func:`mtlx2neural.scene.find_material` resolved it."""
    allow_missing_textures: bool
    application: Application | None
    """The instant the conversion baked ``time``/``frame`` nodes at (None: frame 1 at 24 fps)."""


def _layer_entry(entries: dict, material: str | None) -> str | None:
    """The layer record's material name that ``material`` (None, a name, a prim path or prim name) means;
    None when the record lists nothing matching (``material`` is then resolved against the source)."""
    if material is None:
        return next(iter(entries)) if len(entries) == 1 else None
    return next((name for name, e in entries.items() if names_entry(material, name, e.get("prim"))), None)


def reference_source(filename, material: str | None = None) -> ReferenceSource:
    """Resolve the plugin's ``filename``/``material`` (module docstring): the original asset, the material
    name and the settings of the conversion that recorded it (defaults without a record). ``ValueError``
    for a neural layer that records no source; :class:`mtlx2neural.errors.InputError` for an unknown or
    ambiguous material."""
    path, folder = Path(filename), None
    layer = neural_layer_record(path)
    if layer is not None:
        if layer.source is None:
            raise ValueError(f"{path}: this neural layer records no source asset (mtlx2neural 0.2); pass the "
                             "original .mtlx or USD file as filename")
        name = _layer_entry(layer.materials, material)
        if name is not None:
            material = name
            rel = layer.materials[name].get("folder")
            folder = path.parent / rel if rel else None
        path = layer.source
    src = find_material(path, material)
    if folder is None:
        folder = conversion_outputs(path).folder / material_folder(src.name)
    record = read_record_or_none(folder) if folder.is_dir() else None
    if record is None:
        return ReferenceSource(canonical(path), src.name, False, None)
    allow = bool((record.options or {}).get("allow_missing_textures", False))
    return ReferenceSource(canonical(path), src.name, allow, application_of(record.application))


_CACHE: dict[tuple, tuple[ReferenceSource, ReferenceMaterial]] = {}


def cached_reference(filename, material: str | None = None) -> tuple[ReferenceSource, ReferenceMaterial]:
    """(:func:`reference_source`, its :class:`ReferenceMaterial` on the CPU), built once per process for
    each (file, modification time, material)."""
    path = canonical(filename)
    key = (str(path), os.stat(path).st_mtime_ns if path.exists() else None, material)
    if key not in _CACHE:
        src = reference_source(path, material)
        ref = load_reference(src.path, src.material, device="cpu", allow_missing_textures=src.allow_missing_textures,
                             application=src.application)
        _CACHE[key] = (src, ref)
    return _CACHE[key]


def material_flags(reference: ReferenceMaterial) -> tuple[int, int]:
    """(the BSDF's flags, ``bs.sampled_type``) from the closures the compiled program keeps."""
    cats = {leaf.category for leaf in reference.compiled.program.leaves()}
    flags = 0
    if cats & DIFFUSE_CLOSURES:
        flags |= int(mi.BSDFFlags.DiffuseReflection)
    if cats & GLOSSY_CLOSURES:
        flags |= int(mi.BSDFFlags.GlossyReflection)
    if not flags:  # nothing Mitsuba can name (only unknown or transmissive closures): say both
        flags = int(mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection)
    sampled = mi.BSDFFlags.GlossyReflection if flags & int(mi.BSDFFlags.GlossyReflection) \
        else mi.BSDFFlags.DiffuseReflection
    return flags | int(mi.BSDFFlags.FrontSide), int(sampled)


# ----------------------------------------------------------------------------- the Dr.Jit -> torch bridge


def _rows(x: torch.Tensor, n: int) -> torch.Tensor:
    """A Dr.Jit array as torch sees it (``[C, M]`` for a C-vector of M lanes, ``[M]`` for a Float) as
    contiguous ``[n, C]`` rows; a single lane (M == 1, a broadcast literal) is repeated (a view).

    The copy matters: torch's element-wise kernels on the transposed view (strides (1, M)) run the
    reference about 1.7x slower than on rows (measured 35 ms against 20 ms for 2^16 evals of Plastic),
    and the copy costs a fraction of a millisecond."""
    x = x[None] if x.dim() == 1 else x
    x = x.T.contiguous()
    return x.expand(n, x.shape[1]) if x.shape[0] != n else x


def _width(*xs: torch.Tensor) -> int:
    return max(x.shape[-1] for x in xs)


@dr.wrap(source="drjit", target="torch")
def _eval_torch(material, wi, wo, uv):
    n = _width(wi, wo, uv)
    with torch.no_grad():
        return material.eval(_rows(wi, n), _rows(wo, n), ShadingPoint(uv=_rows(uv, n))).contiguous()


@dr.wrap(source="drjit", target="torch")
def _pdf_torch(material, wi, wo, uv):
    n = _width(wi, wo, uv)
    with torch.no_grad():
        return material.pdf(_rows(wi, n), _rows(wo, n), ShadingPoint(uv=_rows(uv, n))).contiguous()


@dr.wrap(source="drjit", target="torch")
def _eval_pdf_torch(material, wi, wo, uv):
    n = _width(wi, wo, uv)
    wi, wo, at = _rows(wi, n), _rows(wo, n), ShadingPoint(uv=_rows(uv, n))
    with torch.no_grad():
        return material.eval(wi, wo, at).contiguous(), material.pdf(wi, wo, at).contiguous()


@dr.wrap(source="drjit", target="torch")
def _sample_torch(material, wi, sample1, sample2, uv):
    n = _width(wi, sample1, sample2, uv)
    u = torch.cat([_rows(sample2, n), _rows(sample1, n)], 1)  # (direction x, direction y, lobe choice)
    with torch.no_grad():
        wo, weight, pdf = material.sample(_rows(wi, n), u, ShadingPoint(uv=_rows(uv, n)))
    return wo.contiguous(), weight.contiguous(), pdf.contiguous()


@dr.wrap(source="drjit", target="torch")
def _surface_torch(material, what, uv):
    n = _width(uv)
    with torch.no_grad():
        out = getattr(material, what)(ShadingPoint(uv=_rows(uv, n)))
    return None if out is None else out.contiguous()


def _vec3(t) -> mi.Vector3f:
    """A Dr.Jit tensor of shape (N, 3) (rows, as torch returned them) as a 3-vector of N lanes."""
    return dr.unravel(mi.Vector3f, t.array)


def _finite_dir(w: mi.Vector3f, ok: mi.Bool) -> tuple[mi.Vector3f, mi.Bool]:
    """``w`` where ``ok`` and finite, else straight down (below the horizon: every value 0); the mask."""
    ok = ok & dr.all(dr.isfinite(w))
    return dr.select(ok, w, mi.Vector3f(0.0, 0.0, -1.0)), ok


def _finite_uv(uv: mi.Point2f, flip_v: bool) -> mi.Point2f:
    uv = dr.select(dr.isfinite(uv), uv, 0.5)
    return mi.Point2f(uv.x, 1.0 - uv.y) if flip_v else uv


def reference_eval(material, wi, wo, uv) -> mi.Color3f:
    """``material.eval(wi, wo, ShadingPoint(uv=uv))`` (any contract :class:`~mtlx2neural.contract.Material`)
    on Dr.Jit arrays (``mi.Vector3f`` directions, ``mi.Point2f`` uv; single lanes broadcast), cosine
    included, through torch; finite input only."""
    return mi.Color3f(_vec3(_eval_torch(material, wi, wo, uv)))


def reference_pdf(material, wi, wo, uv) -> mi.Float:
    """``material.pdf(...)`` (1/sr) on Dr.Jit arrays, as :func:`reference_eval`."""
    return mi.Float(_pdf_torch(material, wi, wo, uv).array)


def reference_eval_pdf(material, wi, wo, uv) -> tuple[mi.Color3f, mi.Float]:
    """(:func:`reference_eval`, :func:`reference_pdf`) in one torch call."""
    value, pdf = _eval_pdf_torch(material, wi, wo, uv)
    return mi.Color3f(_vec3(value)), mi.Float(pdf.array)


def reference_sample(material, wi, sample1, sample2, uv) -> tuple[mi.Vector3f, mi.Color3f, mi.Float]:
    """``material.sample(wi, u, ShadingPoint(uv=uv))`` with ``u = (sample2.x, sample2.y, sample1)``
    ([N, 3]: the third number picks the lobe): (wo, weight = eval / pdf, pdf in 1/sr)."""
    wo, weight, pdf = _sample_torch(material, wi, sample1, sample2, uv)
    return _vec3(wo), mi.Color3f(_vec3(weight)), mi.Float(pdf.array)


# ----------------------------------------------------------------------------- the plugin


class ReferenceBSDF(mi.BSDF):
    """``mtlx_reference``: eval / pdf / eval_pdf / sample of the torch reference, for every lane at
    once (module docstring: properties, conventions, cost)."""

    def __init__(self, props: mi.Properties):
        mi.BSDF.__init__(self, props)
        if "filename" not in props:
            raise ValueError("mtlx_reference: the 'filename' property (a .mtlx file, USD stage or neural "
                             "layer) is required")
        self.filename = str(props.get("filename"))
        material = props.get("material", None)
        self.source, self.reference = cached_reference(self.filename, None if material is None else str(material))
        self.flip_v = bool(props.get("flip_v", False))
        self.pdf_scale = float(props.get("pdf_scale", 1.0))
        flags, self.sampled_type = material_flags(self.reference)
        self.m_flags = flags
        self.m_components = [flags]

    # -- helpers -------------------------------------------------------------------------
    def _enabled(self, ctx: mi.BSDFContext) -> bool:
        """Whether ``ctx`` asks for this BSDF's single component (``BSDFContext.is_enabled`` for a union of
        flags): any of its lobe types in ``ctx.type_mask``, and component 0 or all. A context asking for
        only some of its types (diffuse but not glossy) still gets the whole material: the reference
        cannot evaluate one kind of lobe alone."""
        return bool(int(ctx.type_mask) & self.m_flags) and int(ctx.component) in (0, ALL_COMPONENTS)

    def _inputs(self, si: mi.SurfaceInteraction3f, wo, active):
        """(wi, wo, uv, mask): directions of inactive or non-finite lanes replaced by one below the horizon."""
        ok = mi.Bool(active)
        wi, ok = _finite_dir(mi.Vector3f(si.wi), ok)
        if wo is not None:
            wo, ok = _finite_dir(mi.Vector3f(wo), ok)
        return wi, wo, _finite_uv(mi.Point2f(si.uv), self.flip_v), ok

    # -- mi.BSDF ---------------------------------------------------------------------------
    def eval(self, ctx, si, wo, active=True):
        """f(wi, wo) * cos(theta_o): ``mi.Color3f`` linear RGB; 0 below the horizon and on inactive lanes."""
        if not self._enabled(ctx):
            return dr.zeros(mi.Color3f)
        wi, wo, uv, ok = self._inputs(si, wo, active)
        return dr.select(ok, reference_eval(self.reference, wi, wo, uv), 0.0)

    def pdf(self, ctx, si, wo, active=True):
        """Solid-angle density (1/sr, no cosine) of :meth:`sample` at ``wo``; times ``pdf_scale``."""
        if not self._enabled(ctx):
            return dr.zeros(mi.Float)
        wi, wo, uv, ok = self._inputs(si, wo, active)
        return dr.select(ok, reference_pdf(self.reference, wi, wo, uv) * self.pdf_scale, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        """(:meth:`eval`, :meth:`pdf`) from one torch call."""
        if not self._enabled(ctx):
            return dr.zeros(mi.Color3f), dr.zeros(mi.Float)
        wi, wo, uv, ok = self._inputs(si, wo, active)
        value, pdf = reference_eval_pdf(self.reference, wi, wo, uv)
        return dr.select(ok, value, 0.0), dr.select(ok, pdf * self.pdf_scale, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        """(``mi.BSDFSample3f``, weight = eval / pdf, cosine included): ``sample1`` picks the lobe,
        ``sample2`` the direction; a failed or below-horizon sample has weight 0 and ``bs.pdf`` 0."""
        bs = dr.zeros(mi.BSDFSample3f)
        if not self._enabled(ctx):
            return bs, dr.zeros(mi.Color3f)
        wi, _, uv, ok = self._inputs(si, None, active)
        # Inactive lanes may carry any number (Mitsuba's mask BSDF divides sample1 by an opacity that can be 0):
        # the reference refuses non-finite input, so they read 0.5 and their results are discarded.
        sample1, sample2 = mi.Float(sample1), mi.Point2f(sample2)
        sample1 = dr.select(ok & dr.isfinite(sample1), sample1, 0.5)
        sample2 = dr.select(ok & dr.isfinite(sample2), sample2, 0.5)
        wo, weight, pdf = reference_sample(self.reference, wi, sample1, sample2, uv)
        ok = ok & (pdf > 0.0)
        bs.wo = wo
        bs.pdf = dr.select(ok, pdf * self.pdf_scale, 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(self.sampled_type)
        bs.sampled_component = mi.UInt32(0)
        return bs, dr.select(ok, weight, 0.0)

    # -- beside the BSDF: emission and opacity ------------------------------------------------
    def emission(self, uv) -> mi.Color3f | None:
        """Emitted radiance at ``uv`` (``mi.Point2f``): linear RGB, no cosine; None when it emits nothing."""
        out = _surface_torch(self.reference, "emission", _finite_uv(mi.Point2f(uv), self.flip_v))
        return None if out is None else mi.Color3f(_vec3(out))

    def opacity(self, uv) -> mi.Float | None:
        """Opacity in [0, 1] at ``uv`` (``mi.Point2f``); None when the material is opaque everywhere."""
        out = _surface_torch(self.reference, "opacity", _finite_uv(mi.Point2f(uv), self.flip_v))
        return None if out is None else mi.Float(out.array)

    def traverse(self, callback):
        """Nothing Mitsuba can differentiate or edit: the material lives in torch."""

    def to_string(self) -> str:
        flags = "|".join(f.name for f in mi.BSDFFlags if int(f) and int(f) & self.m_flags == int(f)
                         and bin(int(f)).count("1") == 1)
        return (f"ReferenceBSDF[\n  filename = \"{self.filename}\",\n  source = \"{self.source.path}\",\n"
                f"  material = \"{self.source.material}\",\n  flags = {flags},\n  flip_v = {self.flip_v},\n"
                f"  application = {self.source.application or 'frame 1 at 24 fps'}\n]")
