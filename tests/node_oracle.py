"""Per-point oracle cases for whole node categories, built from the nodedefs (real MaterialX documents).

:func:`category_nodes` writes one node per nodedef of a category whose inputs are driven per point, so
that every input varies over the points:

* an input named ``texcoord`` (vector2) reads the uv, which spans several units (negative included);
  one named ``position`` (vector3) reads the position;
* every other numeric, non-uniform input reads a smooth function of uv and position,
  ``mid + half * sin(a u + b v + c x + d z + e)`` with seeded coefficients, one of :data:`POOL` per range
  shared by the document's nodes (the inputs of one node read different ones), so that its values sweep
  the range ``[lo, hi]`` that :data:`RANGES` gives for the category or the input
  (default [0.1, 0.9]: positive and away from 0 and 1, where divisions and logarithms are safe);
* integer inputs floor such a value, boolean inputs compare one with 0.5;
* uniform, string and filename inputs keep the nodedef's default.

:func:`compare` evaluates every output of every node with MaterialX's generated Slang code (one shader
for the whole document, :func:`mtlx2neural.oracle.points.mtlx_node_eval`) and with the torch compiler
(:func:`mtlx2neural.graph.node_eval.compile_output`) and returns the error per output.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mtlx2neural.graph.library import standard_library
from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.oracle.points import mtlx_node_eval
from mtlx2neural.oracle.runner import oracle_available

NUMERIC = {"float": 1, "integer": 1, "boolean": 1, "vector2": 2, "vector3": 3, "vector4": 4, "color3": 3,
           "color4": 4}

POOL = 8  # float drivers per range, shared by all inputs of a document
# (category) or (category, input) -> the range the driven values sweep.
_SIGNED = (-3.0, 3.0)  # rounding and sign functions: several integers, both signs
RANGES: dict = {c: _SIGNED for c in ("absval", "ceil", "floor", "round", "sign", "fract", "modulo", "trianglewave")}
RANGES[("range", "inhigh")] = (1.2, 2.0)  # away from inlow: (in - inlow) / (inhigh - inlow) stays moderate
QUANTIZED = {"ifequal"}  # float inputs floored from [-1.5, 1.5]: -2, -1, 0 or 1
INTEGER_RANGE = (-4.0, 4.0)  # integer inputs (floored): several values, both signs


def nodedefs(category: str, skip: tuple[str, ...] = ()) -> list:
    """The nodedefs of ``category`` whose inputs and outputs the node oracle can drive and read
    (numeric, no matrices, no closures), minus the names in ``skip``."""
    out = []
    for nd in standard_library().getMatchingNodeDefs(category):
        if nd.getNodeString() != category or nd.getName() in skip:
            continue
        types = [o.getType() for o in nd.getActiveOutputs()] + [
            i.getType() for i in nd.getActiveInputs() if not (i.getIsUniform() or i.getType() in ("string",
                                                                                                   "filename"))]
        if all(t in NUMERIC for t in types):
            out.append(nd)
    return out


class Builder:
    """Accumulates the XML of one document: shared drivers, then the nodes under test."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.lines = [
            '  <texcoord name="t" type="vector2"/>',
            '  <position name="p" type="vector3"/>',
            '  <separate2 name="ts" type="multioutput"><input name="in" type="vector2" nodename="t"/></separate2>',
            '  <separate3 name="ps" type="multioutput"><input name="in" type="vector3" nodename="p"/></separate3>',
            '  <combine4 name="q" type="vector4"><input name="in1" type="float" nodename="ts" output="outx"/>'
            '<input name="in2" type="float" nodename="ts" output="outy"/>'
            '<input name="in3" type="float" nodename="ps" output="outx"/>'
            '<input name="in4" type="float" nodename="ps" output="outz"/></combine4>',
        ]
        self.count = 0
        self.pools: dict[tuple, list[str]] = {}
        self.shared: dict[tuple, str] = {}
        self.targets: list[tuple[str, str | None, str]] = []  # (node, output or None, type)
        self.categories: dict[str, str] = {}  # node under test -> its category

    def _name(self, stem: str) -> str:
        self.count += 1
        return f"{stem}{self.count}"

    def scalar(self, lo: float, hi: float) -> str:
        """A new float driver sweeping [lo, hi]; returns its node name."""
        a, b, c, d = self.rng.uniform(-2.5, 2.5, 4)
        e = self.rng.uniform(0, 6.283)
        mid, half = (lo + hi) / 2, (hi - lo) / 2
        dp, ph, s, m, o = (self._name(x) for x in ("dp", "ph", "s", "m", "o"))
        self.lines += [
            f'  <dotproduct name="{dp}" type="float"><input name="in1" type="vector4" nodename="q"/>'
            f'<input name="in2" type="vector4" value="{a:.4f}, {b:.4f}, {c:.4f}, {d:.4f}"/></dotproduct>',
            f'  <add name="{ph}" type="float"><input name="in1" type="float" nodename="{dp}"/>'
            f'<input name="in2" type="float" value="{e:.4f}"/></add>',
            f'  <sin name="{s}" type="float"><input name="in" type="float" nodename="{ph}"/></sin>',
            f'  <multiply name="{m}" type="float"><input name="in1" type="float" nodename="{s}"/>'
            f'<input name="in2" type="float" value="{half!r}"/></multiply>',
            f'  <add name="{o}" type="float"><input name="in1" type="float" nodename="{m}"/>'
            f'<input name="in2" type="float" value="{mid!r}"/></add>',
        ]
        return o

    def pooled(self, lo: float, hi: float, slot: int) -> str:
        """Float driver number ``slot`` (of :data:`POOL`) sweeping [lo, hi], made once per document and
        shared by every input that asks for it (so the shader stays small)."""
        pool = self.pools.setdefault((lo, hi), [])
        while len(pool) <= slot % POOL:
            pool.append(self.scalar(lo, hi))
        return pool[slot % POOL]

    def driver(self, mx_type: str, lo: float, hi: float, slot: int = 0) -> str:
        """A node of ``mx_type`` whose channels each sweep [lo, hi] (integers: floored; booleans: > 0.5),
        built from the pooled drivers ``slot``, ``slot + 1``... (cached)."""
        key = (mx_type, lo, hi, slot % POOL)
        if key in self.shared:
            return self.shared[key]
        if mx_type == "float":
            name = self.pooled(lo, hi, slot)
        elif mx_type == "integer":
            name = self._name("i")
            self.lines.append(f'  <floor name="{name}" type="integer"><input name="in" type="float" '
                              f'nodename="{self.pooled(lo, hi, slot)}"/></floor>')
        elif mx_type == "boolean":
            name = self._name("b")
            self.lines.append(f'  <ifgreater name="{name}" type="boolean"><input name="value1" type="float" '
                              f'nodename="{self.pooled(0.0, 1.0, slot)}"/><input name="value2" type="float" '
                              f'value="0.5"/></ifgreater>')
        else:
            n = NUMERIC[mx_type]
            parts = [self.pooled(lo, hi, slot + k) for k in range(n)]
            name = self._name("v")
            ins = "".join(f'<input name="in{k + 1}" type="float" nodename="{p}"/>' for k, p in enumerate(parts))
            self.lines.append(f'  <combine{n} name="{name}" type="{mx_type}">{ins}</combine{n}>')
        self.shared[key] = name
        return name

    def node(self, nd, name: str, values: dict | None = None, sources: dict | None = None) -> None:
        """A node of nodedef ``nd`` named ``name``, its inputs driven (see the module docstring); ``values``
        sets inputs to constants (name -> value string) instead, ``sources`` connects them to named nodes."""
        category = nd.getNodeString()
        outs = nd.getActiveOutputs()
        body = []
        slot = int(self.rng.integers(POOL))
        for inp in nd.getActiveInputs():
            iname, itype = inp.getName(), inp.getType()
            if values and iname in values:
                body.append(f'<input name="{iname}" type="{itype}" value="{values[iname]}"/>')
                continue
            if sources and iname in sources:
                body.append(f'<input name="{iname}" type="{itype}" nodename="{sources[iname]}"/>')
                continue
            if inp.getIsUniform() or itype not in NUMERIC:
                continue
            if iname == "texcoord" and itype == "vector2":
                src = "t"
            elif iname == "position" and itype == "vector3":
                src = "p"
            elif category in QUANTIZED and itype == "float":  # whole numbers, so that equality happens
                src = self._name("f")
                self.lines.append(f'  <floor name="{src}" type="float"><input name="in" type="float" '
                                  f'nodename="{self.pooled(-1.5, 1.5, slot)}"/></floor>')
                slot += 5
            else:
                lo, hi = RANGES.get((category, iname), RANGES.get(category, INTEGER_RANGE if itype == "integer"
                                                                  else (0.1, 0.9)))
                src = self.driver(itype, lo, hi, slot)
                slot += 5  # the next input starts elsewhere in the pool
            body.append(f'<input name="{iname}" type="{itype}" nodename="{src}"/>')
        self.categories[name] = category
        node_type = outs[0].getType() if len(outs) == 1 else "multioutput"
        self.lines.append(f'  <{category} name="{name}" type="{node_type}" nodedef="{nd.getName()}">'
                          f'{"".join(body)}</{category}>')
        for o in outs:
            self.targets.append((name, o.getName() if len(outs) > 1 else None, o.getType()))

    def target(self, name: str, mx_type: str) -> None:
        """Also read node ``name`` (a driver, say) at the points."""
        self.targets.append((name, None, mx_type))

    def document(self):
        import MaterialX as mx

        doc = mx.createDocument()
        mx.readFromXmlString(doc, '<?xml version="1.0"?>\n<materialx version="1.39">\n'
                             + "\n".join(self.lines) + "\n</materialx>\n")
        return doc


def category_nodes(builder: Builder, category: str, skip: tuple[str, ...] = (), part: int | None = None,
                   parts: int = 1) -> int:
    """Add one driven node per drivable nodedef of ``category``; returns how many.

    ``part`` (of ``parts``): only every ``parts``-th nodedef from the ``part``-th on.  MaterialX's Slang
    generator emits a shared helper function once per nodedef that includes it (``burn``, ``dodge``: the
    float function in the color3 and color4 ones), which does not compile when two such nodedefs share a
    shader, so such categories are spread over several documents."""
    nds = nodedefs(category, skip)
    if part is not None:
        nds = nds[part::parts]
    for nd in nds:
        builder.node(nd, f"x_{nd.getName()}")
    return len(nds)


def points(n: int, seed: int, uv_span: float = 3.0, pos_span: float = 3.0):
    """``n`` seeded float32 points: uv in [-uv_span, uv_span]^2, positions in [-pos_span, pos_span]^3."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-uv_span, uv_span, (n, 2)).astype(np.float32)
    pos = rng.uniform(-pos_span, pos_span, (n, 3)).astype(np.float32)
    return uv, pos


def compare(builder: Builder, uv, pos, normal=None, application=None):
    """{(node, output): (torch [N,C], MaterialX [N,C])} for every target of ``builder``'s document;
    ``application``: the instant ``time``/``frame`` fold to on the torch side (``compile_output``)."""
    doc = builder.document()
    targets = [(name, out) if out else name for name, out, _ in builder.targets]
    want = mtlx_node_eval(doc, targets, uv.astype(np.float64), pos.astype(np.float64), normal=normal)
    result = {}
    for (name, out, _), expected in zip(builder.targets, want):
        got = compile_output(doc, name, out, application=application)(torch.from_numpy(uv),
                                                                      torch.from_numpy(pos)).numpy()
        result[(name, out)] = (got.astype(np.float64), expected)
    return result


def max_errors(results, atol: float, rtol: float) -> dict:
    """{target: max |got - want| / (atol + rtol |want|)} (a value above 1 fails)."""
    out = {}
    for key, (got, want) in results.items():
        assert got.shape == want.shape, (key, got.shape, want.shape)
        out[key] = float((np.abs(got - want) / (atol + rtol * np.abs(want))).max())
    return out


def require_oracle() -> None:
    """Skip the calling test, with the reason, when MaterialX's Slang oracle cannot run here."""
    ok, reason = oracle_available()
    if not ok:
        pytest.skip(f"MaterialX Slang oracle unavailable: {reason}")


def assert_within(results, atol: float, rtol: float) -> None:
    """Fail naming every target whose max |torch - MaterialX| exceeds ``atol + rtol |MaterialX|``."""
    bad = {k: v for k, v in max_errors(results, atol, rtol).items() if v > 1.0}
    assert not bad, f"|torch - MaterialX| above {atol} + {rtol} |MaterialX| (ratio): {bad}"
