"""The BSDF program: the closure tree left after folding and lobe pruning.

Combinator semantics are MaterialX's hardware ones: a layer adds the base's
response scaled by the top's throughput; mix interpolates responses and
throughputs; add sums responses and takes max(t1 + t2 - 1, 0) as throughput;
multiply scales the response by a tint clamped to [0, 1] and keeps the
throughput.

Pruning replaces a closure whose contribution folds to nothing by
``Zero(throughput)``, remembering why, then simplifies the combinators around
it. Throughputs only matter below a layer's top, so pruning tracks whether the
parent needs one (``need_tp``) and simplifies more aggressively when it does not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.graph.evaluator import GraphEvaluator
from mtlx2neural.graph.ir import Const, Input, Ref

LOBES = {"oren_nayar_diffuse_bsdf", "burley_diffuse_bsdf", "dielectric_bsdf", "conductor_bsdf",
         "generalized_schlick_bsdf", "sheen_bsdf", "subsurface_bsdf", "translucent_bsdf"}
# Throughput MaterialX leaves when a lobe's weight is below M_FLOAT_EPS.
ZERO_WEIGHT_THROUGHPUT = {"dielectric_bsdf": 1.0, "generalized_schlick_bsdf": 1.0, "sheen_bsdf": 1.0}
EDFS = {"uniform_edf", "conical_edf", "measured_edf", "generalized_schlick_edf"}
VDFS = {"anisotropic_vdf", "absorption_vdf"}
CLOSURE_NODES = LOBES | EDFS | VDFS | {"layer", "surface", "surface_unlit"}
# Deepest nesting of closure combinators (layer, mix, add, multiply) accepted. The closure
# tree is walked recursively here and by the reference; real materials nest a few tens.
MAX_CLOSURE_DEPTH = 256
APPROXIMATED = {"subsurface_bsdf": "subsurface scattering is replaced by MaterialX's hardware wrapped-diffusion "
                                   "approximation for a flat surface"}


@dataclass
class Leaf:
    node: int
    category: str
    path: str


@dataclass
class Zero:
    throughput: float


@dataclass
class Layer:
    top: object
    base: object


@dataclass
class Mix:
    fg: object
    bg: object
    amount: Input
    key: str = ""  # parameter name of the amount: "<node path>.mix"


@dataclass
class Add:
    a: object
    b: object


@dataclass
class Multiply:
    child: object
    tint: Input
    key: str = ""  # parameter name of the tint: "<node path>.in2" (or ".opacity")


def plan_leaves(p) -> list[Leaf]:
    """Leaves of a plan subtree, in evaluation order."""
    if isinstance(p, Leaf):
        return [p]
    if isinstance(p, Layer):
        return plan_leaves(p.top) + plan_leaves(p.base)
    if isinstance(p, Mix):
        return plan_leaves(p.fg) + plan_leaves(p.bg)
    if isinstance(p, Add):
        return plan_leaves(p.a) + plan_leaves(p.b)
    if isinstance(p, Multiply):
        return plan_leaves(p.child)
    return []


@dataclass
class BsdfProgram:
    root: object
    kept: list[dict] = field(default_factory=list)
    pruned: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def leaves(self) -> list[Leaf]:
        return plan_leaves(self.root)

    def inputs(self) -> list[Input]:
        """The IR inputs of the combinators (mix and tint amounts)."""
        return [inp for _, inp in self.amounts()]

    def amounts(self) -> list[tuple[str, Input]]:
        """(parameter name, IR input) of every mix amount and tint, in tree order."""
        ins, stack = [], [self.root]
        while stack:
            p = stack.pop()
            if isinstance(p, Mix):
                ins.append((p.key, p.amount))
                stack += [p.fg, p.bg]
            elif isinstance(p, Multiply):
                ins.append((p.key, p.tint))
                stack.append(p.child)
            elif isinstance(p, Layer):
                stack += [p.top, p.base]
            elif isinstance(p, Add):
                stack += [p.a, p.b]
        return ins


class _Builder:
    def __init__(self, ev: GraphEvaluator):
        self.ev = ev
        self.g = ev.graph
        self.prog = BsdfProgram(None)
        self.depth = 0

    def _enter(self, inp: Input) -> None:
        """Count one more level of closure nesting; refuse a tree deeper than MAX_CLOSURE_DEPTH."""
        self.depth += 1
        if self.depth > MAX_CLOSURE_DEPTH:
            where = self.g[inp.node].path if isinstance(inp, Ref) else "?"
            raise InputError(f"{self.ev.source}: the closure tree is nested more than {MAX_CLOSURE_DEPTH} levels deep "
                             f"(layer/mix/add/multiply of BSDFs, reached at '{where}'); mtlx2neural supports at most "
                             f"{MAX_CLOSURE_DEPTH}. Flatten the chain, e.g. fold a run of multiplies into one node.")

    def const(self, inp: Input):
        if not self.ev.is_constant(inp):
            return None
        v = self.ev.value(inp, {})
        return v if isinstance(v, torch.Tensor) else None

    def prune(self, node_index: int, reason: str, throughput: float) -> Zero:
        n = self.g[node_index]
        self.prog.pruned.append({"closure": n.category, "node": n.path, "reason": reason})
        return Zero(throughput)

    def surface(self, inp: Input):
        """Program of a surfaceshader input (one level deeper in the closure tree)."""
        self._enter(inp)
        try:
            return self._surface(inp)
        finally:
            self.depth -= 1

    def _surface(self, inp: Input):
        if isinstance(inp, Const):
            return Zero(1.0)
        n = self.g[inp.node]
        if n.category == "surface":
            # Emission and opacity are kept beside the BSDF (graph.surface_terms), never folded into it.
            return self.bsdf(n.inputs["bsdf"], need_tp=False)
        if n.category == "surface_unlit":
            self.prog.notes.append(f"'{n.path}' is an unlit surface: no reflectance (its emission is kept)")
            return Zero(1.0)
        if n.category == "mix":
            return self._mix(n, self.surface(n.inputs["fg"]), self.surface(n.inputs["bg"]), n.inputs["mix"])
        if n.category == "add":
            return Add(self.surface(n.inputs["in1"]), self.surface(n.inputs["in2"]))
        if n.category == "multiply":
            return Multiply(self.surface(n.inputs["in1"]), n.inputs["in2"], f"{n.path}.in2")
        raise UnsupportedNodeError(f"{self.ev.source}: surface shader node '{n.path}' ({n.nodedef}) is not "
                                   f"supported as a reflectance; use a BSDF-based shader.", node=n.path)

    def drop(self, subtree, reason: str):
        """Record every lobe of a subtree that a combinator removes."""
        for leaf in plan_leaves(subtree):
            self.prog.pruned.append({"closure": leaf.category, "node": leaf.path, "reason": reason})

    def _mix(self, n, fg, bg, amount):
        c = self.const(amount)
        if c is not None and bool((c <= 0).all()):
            self.drop(fg, f"mix amount of '{n.path}' folds to 0")
            return bg
        if c is not None and bool((c == 1).all()):
            self.drop(bg, f"mix amount of '{n.path}' folds to 1")
            return fg
        if isinstance(fg, Zero) and isinstance(bg, Zero) and fg.throughput == bg.throughput:
            return fg
        return Mix(fg, bg, amount, f"{n.path}.mix")

    def bsdf(self, inp: Input, need_tp: bool):
        """Program of a BSDF input (one level deeper in the closure tree)."""
        self._enter(inp)
        try:
            return self._bsdf(inp, need_tp)
        finally:
            self.depth -= 1

    def _bsdf(self, inp: Input, need_tp: bool):
        if isinstance(inp, Const):
            return Zero(1.0)  # an unconnected BSDF input is MaterialX's BSDF(0, 1)
        i = inp.node
        n = self.g[i]
        cat = n.category
        if n.type == "VDF":
            return Zero(1.0)  # volumes act only on transmission in MaterialX's hardware shading
        if cat in LOBES:
            return self._lobe(i)
        if cat == "layer":
            top = self.bsdf(n.inputs["top"], True)
            base = self.bsdf(n.inputs["base"], need_tp)
            if isinstance(top, Zero):
                if top.throughput == 1.0:
                    return base
                if top.throughput == 0.0:
                    self.drop(base, f"below the opaque top of layer '{n.path}'")
                    return Zero(0.0)
            if isinstance(base, Zero) and (not need_tp or base.throughput == 1.0):
                return top
            return Layer(top, base)
        if cat == "mix":
            return self._mix(n, self.bsdf(n.inputs["fg"], need_tp), self.bsdf(n.inputs["bg"], need_tp), n.inputs["mix"])
        if cat == "add":
            a, b = self.bsdf(n.inputs["in1"], need_tp), self.bsdf(n.inputs["in2"], need_tp)
            for x, y in ((a, b), (b, a)):
                if isinstance(x, Zero) and (x.throughput == 1.0 or not need_tp):
                    return y
            return Add(a, b)
        if cat == "multiply":
            child = self.bsdf(n.inputs["in1"], need_tp)
            if isinstance(child, Zero):
                return child
            c = self.const(n.inputs["in2"])
            if c is not None and bool((c >= 1).all()):
                return child
            if c is not None and bool((c <= 0).all()) and not need_tp:
                self.drop(child, f"tint of '{n.path}' folds to 0")
                return Zero(0.0)
            return Multiply(child, n.inputs["in2"], f"{n.path}.in2")
        raise UnsupportedNodeError(f"{self.ev.source}: BSDF node '{n.path}' ({n.nodedef}) is not supported by "
                                   f"the reflectance reference.", node=n.path)

    def _lobe(self, i: int):
        n = self.g[i]
        cat = n.category
        zero_tp = ZERO_WEIGHT_THROUGHPUT.get(cat, 0.0)
        w = self.const(n.inputs["weight"])
        if w is not None and bool((w < 1e-8).all()):
            return self.prune(i, "weight folds to 0", zero_tp)
        if cat in ("dielectric_bsdf", "generalized_schlick_bsdf"):
            mode = self.ev.value(n.inputs["scatter_mode"], {})
            if mode == "T":
                return self.prune(i, "transmission only (scatter_mode T): contributes nothing to reflection, "
                                      "as in MaterialX's hardware shading", 1.0)
            if mode == "RT":
                self.prog.notes.append(f"{n.path}: transmitted part of scatter_mode RT dropped (reflection only)")
        if cat == "translucent_bsdf":
            nrm = n.inputs["normal"]
            c = self.const(nrm)
            if c is not None and bool(torch.allclose(c, torch.tensor([[0.0, 0.0, 1.0]], dtype=c.dtype))):
                return self.prune(i, "translucent: lit from the back side only; no reflection with the "
                                     "geometric normal", 0.0)
        if cat in APPROXIMATED:
            self.prog.notes.append(f"{n.path}: {APPROXIMATED[cat]}")
        return Leaf(i, cat, n.path)


def build_program(ev: GraphEvaluator, root: Input) -> BsdfProgram:
    """Fold, prune and simplify the closure tree feeding the material's surface shader."""
    b = _Builder(ev)
    b.prog.root = b.surface(root)
    b.prog.kept = [{"closure": leaf.category, "node": leaf.path} for leaf in b.prog.leaves()]
    kept_paths = {leaf.path for leaf in b.prog.leaves()}
    # A lobe shared by several branches is kept if any branch keeps it; report each prune once.
    seen, pruned = set(), []
    for entry in b.prog.pruned:
        if entry["node"] not in kept_paths and entry["node"] not in seen:
            seen.add(entry["node"])
            pruned.append(entry)
    b.prog.pruned = pruned
    b.prog.notes = [note for note in b.prog.notes
                    if not any(note.startswith(p + ":") for p in _lobe_paths(b) - kept_paths)]
    return b.prog


def _lobe_paths(b: "_Builder") -> set[str]:
    return {b.g[i].path for i in range(len(b.g.nodes)) if b.g[i].category in LOBES}
