"""What a surface shader adds besides its BSDF: emitted radiance and opacity (coverage).

The BSDF program (:mod:`.bsdf_program`) keeps reflection only. A ``surface`` node also carries an
EDF (light the surface emits) and an ``opacity`` (the share of the pixel the surface covers); both are
kept here as their own per-point values, never folded into the BRDF, so every consumer can apply them
as MaterialX's hardware shading does: ``colour = (reflected + emitted) * opacity``, the rest of the
pixel showing what lies behind.

**Emission** is a sum of terms, each a ``uniform_edf``'s ``color`` (radiance in the document's
working space, linear RGB, the same in every direction, so no cosine) times the factors the
combinators above it apply: ``multiply`` (EDF or surfaceshader) by its ``in2``, ``mix`` by its amount
(or 1 - amount for the background), ``add`` concatenates. ``surface_unlit`` emits ``emission *
emission_color``. An EDF that depends on direction (``conical_edf``, ``measured_edf``,
a directional light profile) is refused: it is left out and named in :attr:`SurfaceTerms.refused`
(the CLI and ``inspect`` print it), never dropped silently. ``generalized_schlick_edf`` (standard_surface's
coat over its emission) is kept at its value along the normal, ``color0`` times its base, and noted in
:attr:`SurfaceTerms.approximated`. A ``mix`` whose amount folds to 0 or 1 keeps one side only.

**Opacity** is the ``surface`` node's ``opacity`` input after the shading model's own graph: for
UsdPreviewSurface with ``opacityThreshold`` > 0 and glTF's ``alpha_mode`` MASK that graph already
thresholds it (0 or 1: a cut-out); BLEND, standard_surface's and OpenPBR's ``opacity``/
``geometry_opacity`` give a fraction. A mix of surface shaders mixes their opacities. Transmission
(refraction through glass) is not opacity and is not modelled (:mod:`.bsdf_program` prunes it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from mtlx2neural.graph.evaluator import GraphEvaluator
from mtlx2neural.graph.ir import Const, Input, Ref

DIRECTIONAL_EDFS = {"conical_edf": "emits into a cone about the normal",
                    "measured_edf": "emits by a measured (IES) profile"}


@dataclass(frozen=True)
class Factor:
    """One factor of a term: ``value`` (float or color3), or ``1 - value`` when ``complement``."""

    value: Input
    complement: bool = False


@dataclass(frozen=True)
class Term:
    """``value`` times every factor: one emitter's radiance, or one surface's opacity."""

    value: Input
    factors: tuple[Factor, ...] = ()
    node: str = ""  # the MaterialX path of the EDF or surface it comes from

    def times(self, factor: Factor) -> Term:
        return Term(self.value, self.factors + (factor,), self.node)


@dataclass
class SurfaceTerms:
    """A material's emission and opacity as sums of :class:`Term` (module docstring)."""

    emission: list[Term] = field(default_factory=list)
    """Terms of emitted radiance (color3, linear working-space RGB, W sr^-1 m^-2 by MaterialX's convention)."""
    opacity: list[Term] | None = None
    """Terms of opacity in [0, 1] (float); None: opaque everywhere (no surface node sets it)."""
    refused: list[str] = field(default_factory=list)
    """Direction-dependent EDFs left out, each with its node path and why."""
    approximated: list[str] = field(default_factory=list)
    """EDFs kept at their value along the normal (``generalized_schlick_edf``), with their node path."""

    def inputs(self) -> list[Input]:
        """Every IR input the terms read (values and factors)."""
        out = []
        for t in self.emission + (self.opacity or []):
            out += [t.value] + [f.value for f in t.factors]
        return out


def _value(ev: GraphEvaluator, inp: Input, env: dict, n: int) -> torch.Tensor:
    v = ev.value(inp, env)
    return v.expand(n, -1) if v.shape[0] == 1 else v


def evaluate(ev: GraphEvaluator, terms: list[Term], env: dict, n: int, width: int) -> torch.Tensor:
    """Sum of ``terms`` [n, width] from an environment ``env`` of :meth:`GraphEvaluator.run`
    (a float factor scales every channel; a color3 factor channel by channel)."""
    total = torch.zeros(n, width, dtype=ev.dtype, device=ev.device)
    for t in terms:
        v = _value(ev, t.value, env, n)[:, :width]
        for f in t.factors:
            x = _value(ev, f.value, env, n)[:, :width]
            v = v * ((1.0 - x) if f.complement else x)
        total = total + v
    return total


class _Walker:
    def __init__(self, ev: GraphEvaluator):
        self.ev, self.g = ev, ev.graph
        self.terms = SurfaceTerms()

    def _is_zero(self, inp: Input) -> bool:
        if not self.ev.is_constant(inp):
            return False
        v = self.ev.value(inp, {})
        return isinstance(v, torch.Tensor) and bool((v == 0).all())

    def _constant(self, inp: Input) -> float | None:
        """0.0 or 1.0 when ``inp`` folds to that everywhere, else None."""
        if not self.ev.is_constant(inp):
            return None
        v = self.ev.value(inp, {})
        if isinstance(v, torch.Tensor):
            for c in (0.0, 1.0):
                if bool((v == c).all()):
                    return c
        return None

    def edf(self, inp: Input, factors: tuple[Factor, ...]) -> list[Term]:
        if isinstance(inp, Const):
            return []  # an unconnected EDF emits nothing
        n = self.g[inp.node]
        if n.category == "uniform_edf":
            c = n.inputs["color"]
            return [] if self._is_zero(c) else [Term(c, factors, n.path)]
        if n.category in DIRECTIONAL_EDFS:
            if "color" not in n.inputs or not self._is_zero(n.inputs["color"]):
                self.terms.refused.append(f"{n.category} '{n.path}' {DIRECTIONAL_EDFS[n.category]}: "
                                          f"direction-dependent emission is not modelled, left out")
            return []
        if n.category == "generalized_schlick_edf":
            terms = self.edf(n.inputs["base"], factors + (Factor(n.inputs["color0"]),))
            if terms:
                self.terms.approximated.append(f"generalized_schlick_edf '{n.path}' scales its base by the view "
                                               f"angle: kept at its value along the normal (color0)")
            return terms
        if n.category == "add":
            return self.edf(n.inputs["in1"], factors) + self.edf(n.inputs["in2"], factors)
        if n.category == "mix":
            m = n.inputs["mix"]
            c = self._constant(m)
            fg = [] if c == 0.0 else self.edf(n.inputs["fg"], factors + ((Factor(m),) if c is None else ()))
            bg = [] if c == 1.0 else self.edf(n.inputs["bg"], factors + ((Factor(m, True),) if c is None else ()))
            return fg + bg
        if n.category == "multiply":
            return self.edf(n.inputs["in1"], factors + (Factor(n.inputs["in2"]),))
        self.terms.refused.append(f"EDF node '{n.path}' ({n.category}) is not supported: its emission is left out")
        return []

    def surface(self, inp: Input, factors: tuple[Factor, ...], emission: list, opacity: list) -> None:
        """Append the emission and opacity terms of surfaceshader ``inp`` under ``factors``."""
        if isinstance(inp, Const):
            return
        n = self.g[inp.node]
        if n.category == "surface":
            edf = n.inputs.get("edf")
            if isinstance(edf, Ref):
                emission += self.edf(edf, factors)
            op = n.inputs.get("opacity")
            opacity.append(Term(op if op is not None else Const((1.0,), "float"), factors, n.path))
        elif n.category == "surface_unlit":
            emission.append(Term(n.inputs["emission_color"], factors + (Factor(n.inputs["emission"]),), n.path))
            opacity.append(Term(n.inputs.get("opacity", Const((1.0,), "float")), factors, n.path))
        elif n.category == "mix":
            m = n.inputs["mix"]
            self.surface(n.inputs["fg"], factors + (Factor(m),), emission, opacity)
            self.surface(n.inputs["bg"], factors + (Factor(m, True),), emission, opacity)
        elif n.category == "add":  # colours add; the combined shader covers what either covers
            self.surface(n.inputs["in1"], factors, emission, opacity)
            self.surface(n.inputs["in2"], factors, emission, [])
        elif n.category == "multiply":  # scales the colour (emission), not the coverage
            scaled = []
            self.surface(n.inputs["in1"], factors, scaled, opacity)
            emission += [t.times(Factor(n.inputs["in2"])) for t in scaled]


def constant_terms(ev: GraphEvaluator, terms: list[Term]) -> bool:
    """Whether every value and factor of ``terms`` folds to a constant (no texture or geometry read)."""
    return all(ev.is_constant(i) for t in terms for i in [t.value] + [f.value for f in t.factors])


def _opaque(ev: GraphEvaluator, terms: list[Term]) -> bool:
    """Whether opacity ``terms`` fold to 1 everywhere (each term's value and factors constant, sum 1)."""
    if not constant_terms(ev, terms):
        return False
    v = evaluate(ev, terms, {}, 1, 1)
    return bool((v >= 1.0 - 1e-6).all())


def surface_terms(ev: GraphEvaluator, root: Input) -> SurfaceTerms:
    """The emission and opacity of the surfaceshader ``root`` (module docstring). Opacity that folds to 1
    everywhere is None (opaque)."""
    w = _Walker(ev)
    emission, opacity = [], []
    w.surface(root, (), emission, opacity)
    w.terms.emission = emission
    w.terms.opacity = None if not opacity or _opaque(ev, opacity) else opacity
    return w.terms
