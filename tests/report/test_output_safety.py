"""``report`` and ``render`` follow the conversion's output rules (:mod:`mtlx2neural.pipeline.output_safety`):
they never write over, or delete, an input of the asset, a file of an export or a folder they did
not create. Every refusal is exit 2, names the path, and leaves every pre-existing file as it was
(hashed before and after). Nothing here trains: the layer is exported from a random model.
"""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import assert_clean_input_error, run_cli, snapshot
from materials import TEXTURED_MTLX
from test_views import exported  # noqa: F401 - the fixture

COMMON = ("--res", "8", "--spp", "1", "--geometry", "plane")


@pytest.fixture
def textured(tmp_path):
    """tex/albedo.png and tex/tex.mtlx reading it."""
    import OpenImageIO as oiio

    folder = tmp_path / "tex"
    folder.mkdir()
    buf = oiio.ImageBuf(oiio.ImageSpec(4, 4, 3, "uint8"))
    buf.set_pixels(oiio.ROI(0, 4, 0, 4, 0, 1, 0, 3), np.full((4, 4, 3), 0.5, np.float32))
    assert buf.write(str(folder / "albedo.png"))
    (folder / "tex.mtlx").write_text(TEXTURED_MTLX)
    return folder


def test_render_refuses_a_png_that_would_overwrite_a_texture_of_the_input(textured, tmp_path, capsys):
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "render", textured / "tex.mtlx", "--model", "reference",
                             "-o", textured / "albedo.exr", *COMMON)
    assert_clean_input_error(code, out, err, str(textured / "albedo.png"), "would overwrite", "Nothing was written")
    assert snapshot(tmp_path) == before


def test_render_refuses_outputs_inside_an_export(exported, tmp_path, capsys):  # noqa: F811
    before = snapshot(tmp_path)
    target = exported["files"] / "latents_0.exr"  # a latent texture the layer reads
    code, out, err = run_cli(capsys, "render", exported["layer"], "--model", "neural", "-o", target, *COMMON)
    assert_clean_input_error(code, out, err, str(target), "would overwrite")
    target = exported["files"] / "view.exr"  # a new name, but in the export
    code, out, err = run_cli(capsys, "render", exported["layer"], "--model", "neural", "-o", target, *COMMON)
    assert_clean_input_error(code, out, err, str(target), "inside")
    assert snapshot(tmp_path) == before
    code, out, err = run_cli(capsys, "render", exported["layer"], "--model", "neural",
                             "-o", exported["layer"].with_suffix(".exr"), *COMMON)
    assert code == 0, err  # beside the layer, outside the export: fine
    assert exported["layer"].with_suffix(".png").is_file()


def test_report_refuses_a_folder_it_did_not_write(exported, tmp_path, capsys):  # noqa: F811
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "precious.txt").write_text("x")
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "report", exported["layer"], "-o", mine)
    assert_clean_input_error(code, out, err, str(mine), "did not write")
    # The folder holding the input and the layer: refused before anything is rendered or deleted.
    code, out, err = run_cli(capsys, "report", exported["layer"], "-o", tmp_path)
    assert_clean_input_error(code, out, err, str(tmp_path), "holds")
    # Inside the conversion's export.
    code, out, err = run_cli(capsys, "report", exported["layer"], "-o", exported["files"] / "rep")
    assert_clean_input_error(code, out, err, "conversion's output folder")
    assert snapshot(tmp_path) == before


@pytest.mark.slow
def test_report_reads_the_input_by_the_layers_record_and_under_the_conversions_texture_rules(textured, tmp_path,
                                                                                              capsys):
    code, _, err = run_cli(capsys, textured / "tex.mtlx", "--iterations", "0", "--allow-untrained", "--quiet")
    assert code == 0, err
    # Through the layer of a .mtlx input, the input's textures are still inputs: refused.
    code, out, err = run_cli(capsys, "render", textured / "tex_neural.usda", "--model", "neural",
                             "-o", textured / "albedo.exr", *COMMON)
    assert_clean_input_error(code, out, err, str(textured / "albedo.png"), "would overwrite")
    moved = tmp_path / "moved"
    textured.rename(moved)  # input, layer and output folder move together; summary.json keeps the old path
    layer = moved / "tex_neural.usda"
    fast = ("--analytic-iterations", "2", "--res", "8", "--spp", "1")
    code, _, err = run_cli(capsys, "report", layer, "-o", tmp_path / "rep", *fast)
    assert code == 0, err
    # A texture gone since the conversion (which had it): an error naming it, not a report of other figures.
    (moved / "albedo.png").unlink()
    code, out, err = run_cli(capsys, "report", layer, "-o", tmp_path / "rep", *fast)
    assert_clean_input_error(code, out, err, "albedo.png")
