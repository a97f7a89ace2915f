"""Safe HDR FLIP (:mod:`mtlx2neural.render.flip`): a black, nearly black or non-finite reference gets
a defined figure and a note, never a call on which flip-evaluator ends the process; ordinary
images give exactly flip-evaluator's own figure.

Each degenerate case runs in a child process: on the code before this module, flip-evaluator's
``exit()`` ended that child with rc 255 (it would have ended pytest's worker too).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("flip_evaluator", reason="HDR FLIP needs the flip-evaluator package")

from mtlx2neural.render.renderer import image_errors  # noqa: E402

CHILD = textwrap.dedent("""
    import json, sys
    import numpy as np
    from mtlx2neural.render.renderer import image_errors
    case = sys.argv[1]
    rng = np.random.default_rng(0)
    lit = rng.uniform(0.0, 1.0, (24, 24, 3)).astype(np.float32)
    ref = {"black": np.zeros_like(lit), "faint": np.full_like(lit, 1e-12), "const": np.full_like(lit, 0.5),
           "nan": np.where(rng.uniform(size=lit.shape) < 0.1, np.nan, lit).astype(np.float32)}[case]
    test = {"black": lit, "faint": np.zeros_like(lit), "const": lit, "nan": lit}[case]
    e = image_errors(ref, test)
    print(json.dumps({"flip": e["flip"], "note": e.get("flip_note"), "shape": list(np.shape(e["flip_map"]))}))
""")


def _child(case: str) -> dict:
    r = subprocess.run([sys.executable, "-c", CHILD, case], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"{case}: the process ended (rc {r.returncode}): {r.stdout}{r.stderr}"
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_a_black_reference_against_a_lit_test_is_a_large_defined_error():
    r = _child("black")
    # Black against a uniform [0, 1] image is about the largest error FLIP gives; 0.5 leaves room
    # for the exposure range taken from the test image.
    assert r["flip"] > 0.5 and "reference is black" in r["note"] and r["shape"] == [24, 24, 3]


def test_two_black_images_are_flip_zero():
    r = _child("faint")  # 1e-12: below float32's epsilon, which flip-evaluator's range needs
    assert r["flip"] == 0.0 and "both images are black" in r["note"]


def test_a_constant_reference_and_nan_pixels_are_evaluated():
    assert _child("const")["note"] is None and 0.0 < _child("const")["flip"] < 1.0
    r = _child("nan")
    assert "not finite" in r["note"] and 0.0 < r["flip"] < 1.0


def test_ordinary_images_give_flip_evaluators_own_figure():
    import flip_evaluator

    rng = np.random.default_rng(1)
    ref = rng.uniform(0, 2, (32, 32, 3)).astype(np.float32)
    test = (ref * rng.uniform(0.8, 1.2, ref.shape)).astype(np.float32)
    _, mean, _ = flip_evaluator.evaluate(ref, test, "HDR")
    e = image_errors(ref, test)
    assert e["flip"] == pytest.approx(float(mean), abs=0.0) and "flip_note" not in e  # the same call


def test_a_material_that_renders_black_converts_with_a_warning(tmp_path, capsys):
    """The issue's cut-out case through the CLI: a reference that is black in every view (no base, no
    specular) once made flip-evaluator exit() the whole conversion (rc 255, no message)."""
    from cli_helpers import run_cli
    from materials import document, standard_surface

    asset = tmp_path / "black.mtlx"
    asset.write_text(document(standard_surface("Black", "SR", base=0.0, specular=0.0)))
    code, _, err = run_cli(capsys, asset, "--iterations", "0", "--allow-untrained", "--workers", "1")
    assert code == 0, err
    summary = json.loads((tmp_path / "black_neural" / "Black" / "summary.json").read_text())
    assert any("HDR FLIP" in w and "black" in w for w in summary["warnings"]), summary["warnings"]
    assert all(np.isfinite(summary["flip_per_view"]))
