"""Textures packed inside a ``.usdz`` (:mod:`mtlx2neural.imaging.packages`): read as the loose file
would be, converted through the CLI, and a missing member is an error naming the package."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import run_cli
from materials import usd_painted_ball

from mtlx2neural.errors import InputError
from mtlx2neural.imaging.image_io import read_image

IMAGE_SHADER = '''            def Shader "Img"
            {
                uniform token info:id = "ND_image_color3"
                asset inputs:file = @good.png@
                color3f outputs:out
            }
'''


@pytest.fixture
def package(tmp_path):
    """tmp/pkg/texq.usdz: a ball whose base colour reads good.png, packed beside it by USD."""
    import OpenImageIO as oiio
    from pxr import Sdf, UsdUtils

    work = tmp_path / "work"
    work.mkdir()
    rng = np.random.default_rng(0)
    buf = oiio.ImageBuf(oiio.ImageSpec(8, 8, 3, "uint8"))
    buf.set_pixels(oiio.ROI(0, 8, 0, 8, 0, 1, 0, 3), rng.uniform(size=(8, 8, 3)).astype(np.float32))
    assert buf.write(str(work / "good.png"))
    (work / "texq.usda").write_text(usd_painted_ball(
        "color3f inputs:base_color.connect = </World/Looks/Paint/Img.outputs:out>", IMAGE_SHADER,
        metadata='(\n    defaultPrim = "World"\n)\n'))
    (tmp_path / "pkg").mkdir()
    out = tmp_path / "pkg" / "texq.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(work / "texq.usda")), str(out))
    return out, work / "good.png"


def test_a_packed_texture_reads_as_the_loose_file(package):
    usdz, loose = package
    import zipfile

    (member,) = [n for n in zipfile.ZipFile(usdz).namelist() if n.endswith("good.png")]
    packed = read_image(f"{usdz}[{member}]")
    assert np.array_equal(packed.raw, read_image(loose).raw)  # the same bytes decoded: exactly equal
    with pytest.raises(InputError, match=r"texq\.usdz holds no member 'nope.png'"):
        read_image(f"{usdz}[nope.png]")


@pytest.mark.slow
def test_a_usdz_with_packed_textures_converts(package, capsys):
    usdz, loose = package
    loose.unlink()  # only the packed copy exists
    code, _, err = run_cli(capsys, usdz, "--iterations", "0", "--allow-untrained", "--quiet", "--workers", "1")
    assert code == 0, err
    assert (usdz.parent / "texq_neural.usda").is_file()


def test_a_damaged_packed_texture_is_named_by_its_package_path(tmp_path):
    import zipfile

    usdz = tmp_path / "bad.usdz"
    with zipfile.ZipFile(usdz, "w", zipfile.ZIP_STORED) as z:
        z.writestr("tex/cut.png", b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # a PNG signature, then nothing usable
    with pytest.raises(InputError, match=r"bad\.usdz\[tex/cut\.png\]"):
        read_image(f"{usdz}[tex/cut.png]")
