"""The batched torch reference BRDF of one compiled material (``m2n.load_reference``).

It implements :class:`mtlx2neural.contract.Material`, as the neural and analytic materials do.
Conventions (docs/ARCHITECTURE.md; the input contract is :mod:`mtlx2neural.contract`): local
shading frame with z the geometric normal and x
the tangent; ``wi`` points to the viewer, ``wo`` to the light, both away from
the surface. ``eval`` returns f(wi, wo) * max(0, wo.z) in linear RGB and is 0
when either direction is at or below the horizon. Reflection only. Directions of
any length are normalised (a zero vector counts as below the horizon); any real
dtype is accepted and converted to the material's (float32), in which results come
back; NaN or Inf input raises ``ValueError``.

Where: ``at`` is a :class:`~mtlx2neural.contract.ShadingPoint` (or a ``[N, 2]`` uv tensor). The
reference uses its ``uv`` (default (0.5, 0.5)) and ``params`` (overrides by name, e.g. prefiltered
values from a ``ParameterStack``); it is not prefiltered, so ``lod`` and ``u_level`` are checked but
ignored: it point-samples its graph at ``uv``. For callers written before ShadingPoint, ``eval``,
``pdf`` and ``sample`` also take keyword-only ``uv=`` and ``params=``, which fill those fields of ``at``.

Sampling picks one live lobe with probability proportional to the luminance of
its estimated energy times the factors the combinators above it apply (layer
throughput, mix amount, tint), then samples that lobe. ``pdf`` is the resulting
one-sample mixture density restricted to the upper hemisphere: it is 0 when
``wi`` or ``wo`` is at or below the horizon, where a sampled direction gets
weight 0 and pdf 0 (so ``pdf`` integrates to 1 minus the probability of such a
failed sample). ``weight = eval / pdf``.

The ``nan_to_num`` guards below act on internal numerics only (lobe formulas at
grazing angles, extreme parameters): input NaN and Inf never get that far.
"""

from __future__ import annotations

import torch

from mtlx2neural.contract import (
    ShadingPoint,
    above_horizon,
    as_point,
    estimate_albedo,
    normalize_directions,
    prepare_direction,
    prepare_directions,
    prepare_point,
    prepare_values,
    zero_below_horizon,
)
from mtlx2neural.graph.bsdf_program import Add, Layer, Leaf, Mix, Multiply, Zero
from mtlx2neural.graph.compile import CompiledMaterial
from mtlx2neural.graph.surface_terms import evaluate
from mtlx2neural.reference.closures import LOBE_CLASSES
from mtlx2neural.reference.tree import (
    AddNode,
    LayerNode,
    LobeNode,
    MixNode,
    MultiplyNode,
    ZeroNode,
)
from mtlx2neural.reference.vec import INV_PI, cosine_sample, luminance

DEFAULT_UV = (0.5, 0.5)


def _value(response: torch.Tensor, above: torch.Tensor) -> torch.Tensor:
    """What :meth:`ReferenceMaterial.eval` returns of a tree's raw ``response`` [N, 1 or 3]: finite, 0 where
    ``above`` ([N, 1], both directions above the horizon) is False, RGB [N, 3]."""
    response = torch.where(above, _finite(response), 0.0)
    return response.expand(response.shape[0], 3) if response.shape[-1] == 1 else response


def _finite(x: torch.Tensor) -> torch.Tensor:
    """Internal guard for lobe numerics on finite, normalised input (never applied to the input)."""
    return torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)


_AXES = {"normal": (0.0, 0.0, 1.0), "tangent": (1.0, 0.0, 0.0)}


def _default_frame(params: dict) -> dict:
    """A zero-length normal or tangent (authored as 0,0,0) means the geometric axis."""
    for key, axis in _AXES.items():
        v = params.get(key)
        if isinstance(v, torch.Tensor):
            zero = (v * v).sum(-1, keepdim=True) < 1e-12
            if bool(zero.any()):
                params[key] = torch.where(zero, torch.tensor(axis, dtype=v.dtype, device=v.device), v)
    return params


class ReferenceMaterial:
    """eval / sample / pdf / albedo / describe of a compiled MaterialX material on any torch device
    (a :class:`~mtlx2neural.contract.Material`)."""

    def __init__(self, compiled: CompiledMaterial):
        self.compiled = compiled
        self.device = compiled.evaluator.device
        self.dtype = compiled.evaluator.dtype

    # -- building the closure tree for a batch ------------------------------------------
    def _tree(self, n: int, uv, params: dict | None = None):
        ev = self.compiled.evaluator
        env = {}
        params = params or {}
        if self.compiled.spatial_nodes and not self._covers(params):
            if uv is None:
                uv = torch.tensor([DEFAULT_UV], dtype=self.dtype, device=self.device).expand(n, 2)
            env = ev.run(self.compiled.spatial_nodes, uv.to(self.device, self.dtype))
        graph = self.compiled.graph

        def value(key, inp):
            v = params.get(key)
            return v.to(self.device, self.dtype) if v is not None else ev.value(inp, env)

        def build(p):
            if isinstance(p, Leaf):
                lobe_params = {k: value(f"{p.path}.{k}", v) for k, v in graph[p.node].inputs.items()}
                return LobeNode(LOBE_CLASSES[p.category](_default_frame(lobe_params)))
            if isinstance(p, Zero):
                return ZeroNode(p.throughput)
            if isinstance(p, Layer):
                return LayerNode(build(p.top), build(p.base))
            if isinstance(p, Mix):
                return MixNode(build(p.fg), build(p.bg), value(p.key, p.amount))
            if isinstance(p, Add):
                return AddNode(build(p.a), build(p.b))
            if isinstance(p, Multiply):
                return MultiplyNode(build(p.child), value(p.key, p.tint))
            raise TypeError(p)

        return build(self.compiled.program.root)

    def parameters_at(self, uv: torch.Tensor) -> dict:
        """The spatially varying parameters at ``uv`` [N,2], ``{name: [N, width]}``: the material graph
        evaluated once, to pass as ``params`` to several ``eval``/``pdf``/``sample`` calls at the same
        points (``{}`` for a uniform material)."""
        if not self.compiled.spatial_nodes:
            return {}
        ev = self.compiled.evaluator
        env = ev.run(self.compiled.spatial_nodes, uv.to(self.device, self.dtype))
        return {k: ev.value(inp, env) for k, inp, _ in self.compiled.varying_parameters()}

    def _covers(self, params: dict) -> bool:
        """Whether ``params`` overrides every spatially varying parameter (no graph evaluation needed)."""
        return bool(params) and all(k in params for k, _, _ in self.compiled.varying_parameters())

    def _directions(self, wi, wo):
        return prepare_directions(wi, wo, self.dtype, self.device)

    def _point(self, at, uv=None, params=None) -> ShadingPoint:
        """``at`` checked and converted, with the keyword-only ``uv``/``params`` of older callers filled in."""
        p = as_point(at)
        if uv is not None or params is not None:
            if (uv is not None and p.uv is not None) or (params is not None and p.params is not None):
                raise ValueError("uv or params given twice: in at and as a keyword argument")
            p = ShadingPoint(p.uv if uv is None else uv, p.lod, p.u_level, p.params if params is None else params)
        return prepare_point(p, self.dtype, self.device)

    # -- public API ----------------------------------------------------------------------
    def eval(self, wi: torch.Tensor, wo: torch.Tensor, at=None, *, uv=None, params: dict | None = None
             ) -> torch.Tensor:
        """f(wi, wo) * max(0, cos theta_o): [N,3] linear RGB, the cosine included (about the material's
        shading normal: wo.z unless it has a normal map); 0 when wi or wo is at or below the horizon.

        ``wi`` (to the viewer), ``wo`` (to the light) [N,3] in the local frame (z normal, x tangent), of any
        length and real dtype (normalised; NaN/Inf raise ValueError). ``at``: a ShadingPoint (its ``uv``
        [N,2] and ``params``, overrides by name as in ``CompiledMaterial.parameters()``; ``lod`` and
        ``u_level`` are ignored) or a [N,2] uv tensor.
        """
        wi, wo = self._directions(wi, wo)
        p = self._point(at, uv, params)
        response, _ = self._tree(wi.shape[0], p.uv, p.params).eval(wi, wo)
        return _value(response, above_horizon(wi, wo))

    def _selection(self, tree, wi):
        leaves = tree.leaves(wi, torch.ones_like(wi))
        if not leaves:
            return [], None
        w = torch.stack([luminance((coef * lobe.energy(wi)).clamp_min(0.0)) for lobe, coef in leaves], -1)
        w = _finite(w)
        total = w.sum(-1, keepdim=True)
        probs = torch.where(total > 0, w / total.clamp_min(1e-30), torch.full_like(w, 1.0 / len(leaves)))
        return [lobe for lobe, _ in leaves], probs

    @staticmethod
    def _mixture_pdf(lobes, probs, wi, wo):
        if not lobes:
            return wo[:, 2].clamp_min(0.0) * INV_PI
        pdfs = torch.stack([_finite(lobe.pdf(wi, wo)) for lobe in lobes], -1)
        return (pdfs * probs).sum(-1)

    def pdf(self, wi: torch.Tensor, wo: torch.Tensor, at=None, *, uv=None, params: dict | None = None
            ) -> torch.Tensor:
        """Solid-angle density [N] (1/sr, no cosine) of :meth:`sample` at ``wo``; 0 when wi or wo is at or
        below the horizon (where :meth:`sample` gives weight 0 and pdf 0). Inputs as for :meth:`eval`."""
        wi, wo = self._directions(wi, wo)
        p = self._point(at, uv, params)
        return self._density(self._tree(wi.shape[0], p.uv, p.params), wi, wo)

    def _density(self, tree, wi, wo, selection=None):
        """:meth:`pdf` from a built tree (``selection``: its :meth:`_selection` at ``wi``, if already made)."""
        lobes, probs = selection if selection is not None else self._selection(tree, wi)
        return zero_below_horizon(self._mixture_pdf(lobes, probs, wi, wo), wi, wo)

    def _eval_pdf_tree(self, tree, wi, wo, selection=None):
        """:meth:`eval_pdf` from a built tree (``wi``, ``wo`` prepared; ``selection`` as for :meth:`_density`)."""
        response, _ = tree.eval(wi, wo)
        return _value(response, above_horizon(wi, wo)), self._density(tree, wi, wo, selection)

    def eval_pdf(self, wi: torch.Tensor, wo: torch.Tensor, at=None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(eval(wi, wo, at), pdf(wi, wo, at))`` from one evaluation of the material's parameters and lobes:
        the same values, bit for bit, for about half the cost of the two calls."""
        wi, wo = self._directions(wi, wo)
        p = self._point(at)
        return self._eval_pdf_tree(self._tree(wi.shape[0], p.uv, p.params), wi, wo)

    def sample(self, wi: torch.Tensor, u: torch.Tensor, at=None, *, uv=None, params: dict | None = None,
               with_value: bool = False):
        """Importance-sample ``wo`` from ``u`` [N,2] (or [N,3]: the third number picks the lobe).

        Returns (wo [N,3] unit, local frame, away from the surface; weight [N,3] = eval/pdf, the cosine
        included; pdf [N] = ``pdf(wi, wo)`` per steradian); weight and pdf are 0 for failed samples, for a
        ``wo`` at or below the horizon, and when wi is at or below the horizon. ``wi`` and ``at`` as for
        :meth:`eval`; ``u`` finite (NaN/Inf raise ValueError). ``with_value``: (wo, ``eval(wi, wo)``, pdf)
        instead, the value bit for bit as :meth:`eval` gives it, without evaluating the material again.
        """
        wi = prepare_direction("wi", wi, self.dtype, self.device)
        n = wi.shape[0]
        u = prepare_values("u", u, self.dtype, self.device, rows=n, width=(2, 3))
        p = self._point(at, uv, params)
        tree = self._tree(n, p.uv, p.params)
        return self._sample_tree(tree, wi, u, with_value)

    def sample_and_eval_pdf(self, wi: torch.Tensor, u: torch.Tensor, wo: torch.Tensor, at=None):
        """``(sample(wi, u, at, with_value=True), eval_pdf(wi, wo, at))`` from one evaluation of the
        material's parameters, lobes and lobe selection: the same values, bit for bit, for less than the two
        calls (the mollified training targets ask for both at every footprint point,
        :func:`~mtlx2neural.train.mollify.cone_mean`). ``wo`` [N,3] (local frame, any length) is the second
        direction, evaluated beside the sampled one; inputs otherwise as for :meth:`sample`."""
        wi, wo = self._directions(wi, wo)
        u = prepare_values("u", u, self.dtype, self.device, rows=wi.shape[0], width=(2, 3))
        p = self._point(at)
        tree = self._tree(wi.shape[0], p.uv, p.params)
        selection = self._selection(tree, wi)
        return self._sample_tree(tree, wi, u, True, selection), self._eval_pdf_tree(tree, wi, wo, selection)

    def _sample_tree(self, tree, wi, u, with_value: bool, selection=None):
        """:meth:`sample` from a built tree (``wi`` and ``u`` prepared; ``selection`` as for :meth:`_density`)."""
        n = wi.shape[0]
        lobes, probs = selection if selection is not None else self._selection(tree, wi)
        if not lobes:
            wo = cosine_sample(u[:, :2])
        else:
            cdf = probs.cumsum(-1)
            pick_u = u[:, 2] if u.shape[1] > 2 else u[:, 0]
            k = torch.searchsorted(cdf, pick_u[:, None].clamp(max=1 - 1e-7)).clamp(max=len(lobes) - 1)[:, 0]
            uu = u[:, :2].clone()
            if u.shape[1] == 2:  # reuse the first number: rescale it within the chosen lobe's interval
                lo = torch.where(k > 0, cdf.gather(1, (k - 1).clamp_min(0)[:, None])[:, 0], torch.zeros_like(u[:, 0]))
                pk = probs.gather(1, k[:, None])[:, 0]
                uu[:, 0] = ((u[:, 0] - lo) / pk.clamp_min(1e-12)).clamp(0.0, 1.0 - 1e-7)
            wo = torch.zeros_like(wi)
            for j, lobe in enumerate(lobes):
                sel = k == j
                if bool(sel.any()):
                    wo = torch.where(sel[:, None], lobe.sample(wi, uu), wo)
        wo = normalize_directions(_finite(wo))  # as pdf() would see it: a failed (zero) sample is below
        pdf = self._mixture_pdf(lobes, probs, wi, wo)
        response, _ = tree.eval(wi, wo)
        response = response.expand(n, 3)
        above = above_horizon(wi, wo)
        ok = above & (pdf[:, None] > 0)
        weight = torch.where(ok, _finite(response) / pdf.clamp_min(1e-30)[:, None], torch.zeros_like(response))
        pdf = torch.where(above[:, 0], pdf, torch.zeros_like(pdf))
        if with_value:
            return wo, _value(response, above), pdf
        return wo, _finite(weight), pdf

    def albedo(self, wi: torch.Tensor, at=None, samples: int = 256, seed: int = 0) -> torch.Tensor:
        """Directional albedo [N,3] (the integral of eval, cosine included, over wo):
        :func:`~mtlx2neural.contract.estimate_albedo`, the mean of sample() weights over ``samples`` Sobol
        points; 0 when wi is at or below the horizon. ``wi`` and ``at`` as for :meth:`eval`."""
        wi = prepare_direction("wi", wi, self.dtype, self.device)
        return estimate_albedo(self, wi, at, samples, seed)

    def _surface(self, terms, at, width: int) -> torch.Tensor:
        """Sum of surface ``terms`` [N, width] at ``at``'s uv (default (0.5, 0.5), one row)."""
        p = self._point(at)
        uv = p.uv if p.uv is not None else torch.tensor([DEFAULT_UV], dtype=self.dtype, device=self.device)
        ev = self.compiled.evaluator
        env = ev.run(self.compiled.surface_nodes, uv) if self.compiled.surface_nodes else {}
        return _finite(evaluate(ev, terms, env, uv.shape[0], width))

    def emission(self, at=None) -> torch.Tensor | None:
        """Emitted radiance [N,3] (linear working-space RGB, no cosine: the same in every direction) at
        ``at``'s uv, the material graph's EDF evaluated there (:mod:`mtlx2neural.graph.surface_terms`);
        None when the material emits nothing. Added to the reflected light by the renderers."""
        terms = self.compiled.surface.emission
        return self._surface(terms, at, 3) if terms else None

    def opacity(self, at=None) -> torch.Tensor | None:
        """Opacity [N] in [0, 1] at ``at``'s uv (the surface node's ``opacity``, a cut-out's already 0 or 1
        from its shading model's threshold); None when the material is opaque everywhere."""
        terms = self.compiled.surface.opacity
        return self._surface(terms, at, 1)[:, 0].clamp(0.0, 1.0) if terms else None

    def describe(self) -> dict:
        """Lobes kept and pruned (with reasons), approximations, spatial inputs, textures."""
        return self.compiled.describe()
