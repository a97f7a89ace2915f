"""Texture paths spelled with another case (imaging/resolve.py), on real files in tmp_path."""

from __future__ import annotations

import pytest

from mtlx2neural.errors import InputError
from mtlx2neural.imaging.resolve import case_matches, on_disk, resolve_case


@pytest.fixture
def case_sensitive(tmp_path):
    """``tmp_path``, skipping when its file system ignores case (then nothing is ever mis-cased)."""
    probe = tmp_path / "probe"
    probe.write_bytes(b"")
    if (tmp_path / "PROBE").exists():
        pytest.skip("the temporary folder's file system is case-insensitive")
    probe.unlink()
    return tmp_path


def test_one_match_ignoring_case_is_used_with_a_warning_naming_both(case_sensitive):
    real = case_sensitive / "basecolor.png"
    real.write_bytes(b"png")
    asked = str(case_sensitive / "baseColor.png")
    found, warning = resolve_case(asked, node="albedo")
    assert found == str(real)
    assert asked in warning and str(real) in warning and "albedo" in warning
    assert on_disk(asked) == str(real)


def test_folder_components_are_matched_ignoring_case_too(case_sensitive):
    (case_sensitive / "Textures").mkdir()
    real = case_sensitive / "Textures" / "Wood_BaseColor.png"
    real.write_bytes(b"png")
    found, warning = resolve_case(str(case_sensitive / "textures" / "wood_basecolor.PNG"))
    assert found == str(real) and warning is not None


def test_existing_missing_and_tiled_paths_are_returned_unchanged(case_sensitive):
    real = case_sensitive / "basecolor.png"
    real.write_bytes(b"png")
    assert resolve_case(str(real), strict=True) == (str(real), None)  # exact spelling: nothing to fix
    missing = str(case_sensitive / "roughness.png")
    assert resolve_case(missing) == (missing, None)  # the reader reports it as missing
    tiled = str(case_sensitive / "BASECOLOR.<UDIM>.png")
    assert resolve_case(tiled) == (tiled, None)
    assert resolve_case("") == ("", None)


def test_two_matches_are_an_error_naming_both(case_sensitive):
    a, b = case_sensitive / "basecolor.png", case_sensitive / "BaseColor.png"
    a.write_bytes(b"a")
    b.write_bytes(b"b")
    asked = str(case_sensitive / "BASECOLOR.png")
    assert case_matches(asked) == sorted([str(a), str(b)])
    with pytest.raises(InputError) as info:
        resolve_case(asked, node="albedo")
    assert str(a) in str(info.value) and str(b) in str(info.value) and info.value.node == "albedo"
    assert on_disk(asked) == asked  # ambiguous: hashes and dependency lists keep the document's spelling


def test_strict_refuses_a_case_mismatch(case_sensitive):
    (case_sensitive / "basecolor.png").write_bytes(b"png")
    with pytest.raises(InputError, match="differs from it only in case.*--strict"):
        resolve_case(str(case_sensitive / "baseColor.png"), node="albedo", strict=True)


def test_a_folder_matching_the_file_name_is_not_a_texture(case_sensitive):
    (case_sensitive / "BaseColor.png").mkdir()
    asked = str(case_sensitive / "basecolor.png")
    assert resolve_case(asked) == (asked, None)
