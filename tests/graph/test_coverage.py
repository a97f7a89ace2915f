"""The coverage table (mtlx2neural.graph.coverage) and its sync with the oracle tests.

Every category that compiles must have an oracle case: a per-point node oracle test module listing it in
``ORACLE_CATEGORIES`` (or the noise test, whose categories are listed here), or, for closures and shaders,
a material of MaterialX's example and test-suite folders that tests/reference/test_against_oracle.py
compares.  The categories that compile without an oracle case yet are listed in ``KNOWN_GAPS`` with the
reason; the test fails when a compiled category is in neither (add its oracle case) or when a gap has
gained a case or stopped compiling (update the list).
"""

from __future__ import annotations

import importlib
from pathlib import Path

import MaterialX as mx
import pytest
from conftest import MTLX_RES

from mtlx2neural.graph.coverage import (
    OUT_OF_SCOPE,
    ROOTS,
    coverage,
    coverage_summary,
    format_coverage,
)
from mtlx2neural.graph.ir import CLOSURE_TYPES
from mtlx2neural.graph.library import standard_library

HERE = Path(__file__).parent
# Per-point node oracle test modules (tests/graph/<module>.py) that declare ORACLE_CATEGORIES.
# test_heightfield's cases are analytic (heighttonormal differentiates over the screen, which the oracle's
# compute kernel has not).
ORACLE_MODULES = ("test_compositing", "test_ramps", "test_blackbody", "test_transforms", "test_stdlib_sweep",
                  "test_heightfield", "test_hextile", "test_matrix", "test_flake", "test_uniform_primvar")
# tests/graph/test_noise.py (written before ORACLE_CATEGORIES): its categories, each checked to be named there.
NOISE = ("noise2d", "noise3d", "fractal2d", "fractal3d", "cellnoise2d", "cellnoise3d", "worleynoise2d",
         "worleynoise3d", "unifiednoise2d", "unifiednoise3d", "randomfloat", "randomcolor")
# The folders tests/reference/test_against_oracle.py compares material by material.
MATERIAL_FOLDERS = ("Materials/Examples/StandardSurface", "Materials/Examples/UsdPreviewSurface",
                    "Materials/TestSuite/pbrlib")
_EMISSION = "emission: the reflectance model drops it, so the material oracle does not compare it"
KNOWN_GAPS = {
    "uniform_edf": _EMISSION, "conical_edf": _EMISSION, "measured_edf": _EMISSION,
    "generalized_schlick_edf": _EMISSION, "LamaEmission": _EMISSION,
    "LamaMix": "its only test material does not compile in MaterialX 1.39.5's Slang generator",
    "disney_principled": "no material of the compared folders uses it",
    "gltf_pbr": "no material of the compared folders uses it",
    "overlay": "MaterialX 1.39.5's Slang generator names a variable 'lerp' in overlay's graph, so the oracle "
               "shader does not compile",
    "ramp": "differs from MaterialX with driven inputs (up to 0.89): not diagnosed yet",
    "ramp_gradient": "differs from MaterialX with driven inputs (up to 0.67): not diagnosed yet",
}
_TEXTURE = "reads a texture file: its per-point oracle case (a texture at many uv) is not written yet"
_PRIMVAR = "reads a primvar, which the per-point oracle does not supply"
KNOWN_GAPS.update({c: _TEXTURE for c in ("image", "tiledimage", "latlongimage", "triplanarprojection",
                                         "UsdUVTexture", "gltf_image", "gltf_colorimage", "gltf_normalmap",
                                         "gltf_anisotropy_image", "gltf_iridescence_thickness")})
KNOWN_GAPS.update({c: _PRIMVAR for c in ("geompropvalue", "UsdPrimvarReader")})


def _module_categories() -> dict[str, tuple[str, ...]]:
    out = {name: tuple(importlib.import_module(name).ORACLE_CATEGORIES) for name in ORACLE_MODULES}
    noise_src = (HERE / "test_noise.py").read_text()
    for c in NOISE:
        stem = c[:-2] if c.endswith(("2d", "3d")) else c
        assert stem in noise_src, f"test_noise.py does not name {c}"
    out["test_noise"] = NOISE
    return out


def _material_categories() -> set[str]:
    cats = set()
    for folder in MATERIAL_FOLDERS:
        for path in sorted((MTLX_RES / folder).rglob("*.mtlx")):
            doc = mx.createDocument()
            try:
                mx.readFromXmlFile(doc, str(path))
            except mx.Exception:
                continue
            cats.update(e.getCategory() for e in doc.traverseTree() if e.isA(mx.Node))
    return cats


def _oracle_cases() -> tuple[set[str], set[str], set[str]]:
    """(compiled categories without the material root, value categories with a node oracle case, all
    categories with an oracle case)."""
    table = coverage()
    compiled = {c for c, row in table.items() if row.status in ("supported", "partial") and c not in ROOTS}
    value_cases = {c for cats in _module_categories().values() for c in cats}
    # A value category needs a node oracle case; a closure-only one may rely on the material oracle.
    materials = _material_categories()
    # (A gap stays a gap although a material uses it: emission and LamaMix are in materials the oracle
    # does not compare.)
    closure_cases = {c for c in compiled if _is_closure(c) and c in materials and c not in KNOWN_GAPS}
    return compiled, value_cases, value_cases | closure_cases


def oracle_figures() -> list[str]:
    """The coverage figures the docs quote (README, BENCHMARKS.md, docs/coverage.md), one line per scope:
    in-scope categories, compiled ones, and compiled ones with an oracle case.  ``PYTHONPATH=tests
    python tests/graph/test_coverage.py`` prints them."""
    table = coverage()
    compiled, _, covered = _oracle_cases()
    lines = []
    for libs, label in ((("stdlib", "pbrlib"), "stdlib + pbrlib"), (None, "all libraries")):
        s = coverage_summary(libs)
        rows = {c for c, row in table.items() if libs is None or row.library in libs}
        lines.append(f"{label}: {s['in_scope']} in scope, {s['supported']} compile fully, {s['partial']} partly; "
                     f"{len(covered & compiled & rows)} of the {len(compiled & rows)} compiled non-root "
                     f"categories have an oracle case; gaps: {', '.join(sorted((compiled & rows) - covered))}")
    return lines


def test_every_compiled_category_has_an_oracle_case():
    if not MTLX_RES.exists():
        pytest.skip("../shared (MaterialX's example materials) is absent: the closure cases cannot be listed")
    compiled, value_cases, covered = _oracle_cases()
    stale = sorted(c for c in value_cases if c not in compiled)
    assert not stale, f"oracle cases for categories that do not compile: {stale}"
    missing = sorted(compiled - covered - set(KNOWN_GAPS))
    assert not missing, f"compiled categories without an oracle case (add one, or a KNOWN_GAPS entry): {missing}"
    closed = sorted(c for c in KNOWN_GAPS if c in covered or c not in compiled)
    assert not closed, f"KNOWN_GAPS entries that now have a case or no longer compile: {closed}"


def _is_closure(category: str) -> bool:
    return all(o.getType() in CLOSURE_TYPES for nd in standard_library().getMatchingNodeDefs(category)
               for o in nd.getActiveOutputs())


def test_coverage_table_statuses():
    table = coverage()
    for c in ("over", "ramplr", "splittb", "blackbody", "transformnormal", "noise3d", "standard_surface",
              "heighttonormal", "bump", "hextiledimage", "hextilednormalmap", "flake2d", "flake3d",
              "transformmatrix", "invertmatrix", "multiply", "extract", "switch"):
        assert table[c].status == "supported", table[c]
    for c in ("viewdirection",):  # nprlib: view-dependent, not a reflectance input
        assert table[c].status == "unsupported" and table[c].reason, table[c]
    for c in OUT_OF_SCOPE:
        assert table[c].status == "out of scope"
    s = coverage_summary()
    assert s["supported"] + s["partial"] + s["unsupported"] == s["in_scope"]
    assert s["supported"] > 100
    text = format_coverage()
    assert "stdlib + pbrlib:" in text and "blackbody" in text


if __name__ == "__main__":  # PYTHONPATH=tests python tests/graph/test_coverage.py
    print("\n".join(oracle_figures()))
