"""Damaged textures are errors that name the file, where they are read: a truncated file that a
decoder half-decodes (libjpeg fills a truncated JPEG with grey and only warns) and a float texture
with NaN or infinite texels. Through the CLI the material is not converted (exit 2) and nothing is
written beside the input.
"""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import assert_clean_input_error, run_cli, snapshot
from conftest import write_float_image
from materials import document, image, standard_surface

from mtlx2neural.errors import InputError
from mtlx2neural.imaging.image_io import read_image


def _jpeg(path, size: int = 128) -> bytes:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(oiio.ImageSpec(size, size, 3, "uint8"))
    rng = np.random.default_rng(0)
    buf.set_pixels(oiio.ROI(0, size, 0, size, 0, 1, 0, 3), rng.uniform(size=(size, size, 3)).astype(np.float32))
    assert buf.write(str(path))
    return path.read_bytes()


def test_a_truncated_jpeg_is_an_error_naming_it(tmp_path):
    full = _jpeg(tmp_path / "full.jpg")
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(full[: len(full) // 3])  # libjpeg decodes this with two thirds grey fill
    assert read_image(tmp_path / "full.jpg").height == 128
    with pytest.raises(InputError, match=r"cut\.jpg.*truncated or corrupt"):
        read_image(cut, node="albedo")


def test_nonfinite_texels_are_an_error_naming_the_file_and_count(tmp_path):
    img = np.full((8, 8, 3), 0.5, np.float32)
    img[2, 3] = np.nan
    img[5, 1, 0] = np.inf
    write_float_image(tmp_path / "bad.exr", img)
    with pytest.raises(InputError, match=r"bad\.exr.* 2 texel\(s\) that are NaN or infinite.*column 3, row 2"):
        read_image(tmp_path / "bad.exr")


@pytest.mark.parametrize("damage", ["truncated_jpeg", "nan_exr"])
def test_the_cli_refuses_a_material_with_a_damaged_texture(tmp_path, capsys, damage):
    if damage == "truncated_jpeg":
        name = "albedo.jpg"
        full = _jpeg(tmp_path / name)
        (tmp_path / name).write_bytes(full[: len(full) // 2])
    else:
        name = "albedo.exr"
        img = np.full((8, 8, 3), 0.5, np.float32)
        img[0, 0] = np.inf
        write_float_image(tmp_path / name, img)
    (tmp_path / "m.mtlx").write_text(document(image("albedo", name),
                                              standard_surface("M", "SR", base_color={"node": "albedo"})))
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, tmp_path / "m.mtlx", "--iterations", "0", "--allow-untrained", "--quiet")
    assert_clean_input_error(code, out, err, str(tmp_path / name))
    assert snapshot(tmp_path) == before
