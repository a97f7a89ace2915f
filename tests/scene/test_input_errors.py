"""Input problems caught by ``inspect`` and before any training, with a clear InputError (issue 15).

* enumerated inputs (``uaddressmode="bogus"``) are checked against the nodedef's ``enum``;
* very long node chains compile, evaluate and inspect without RecursionError;
* unreadable files are reported as permission problems, not as missing includes;
* ``inspect --json`` stdout is JSON even when OpenImageIO has something to say.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import MaterialX as mx
import numpy as np
import pytest
import torch
from conftest import SIMPLE_MTLX, unprivileged_prefix, write_float_image

from mtlx2neural.cli import main
from mtlx2neural.errors import InputError
from mtlx2neural.graph import compile_material
from mtlx2neural.scene import mtlx_file


def _material(body: str, shader_inputs: str) -> str:
    """A document: ``body`` elements plus a standard_surface M whose inputs are ``shader_inputs``."""
    return (f'<?xml version="1.0"?>\n<materialx version="1.39">\n{body}\n'
            f'  <standard_surface name="SR" type="surfaceshader">{shader_inputs}</standard_surface>\n'
            '  <surfacematerial name="M" type="material">\n'
            '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n'
            "  </surfacematerial>\n</materialx>\n")


def _image(name: str = "img", extra: str = "", file: str = "tex.png") -> str:
    return (f'  <image name="{name}" type="color3">\n    <input name="file" type="filename" value="{file}" />\n'
            f"    {extra}\n  </image>")


BASE_FROM_IMG = '<input name="base_color" type="color3" nodename="img" />'


def _texture(folder: Path, name: str = "tex.png") -> Path:
    path = folder / name
    write_float_image(path, np.full((4, 4, 3), 0.5, np.float32))
    return path


def _inspect(capsys, *argv) -> tuple[int, str, str]:
    code = main(["inspect", *[str(a) for a in argv]])
    out, err = capsys.readouterr()
    return code, out, err


# ----------------------------------------------------------------------------- 1. enumerated inputs

ENUM_CASES = {
    # id: (document, strings the message must name besides the file)
    "uaddressmode": (_material(_image(extra='<input name="uaddressmode" type="string" value="bogus" />'),
                               BASE_FROM_IMG),
                     ["'img'", "uaddressmode", "'bogus'", "constant, clamp, periodic, mirror"]),
    "filtertype": (_material(_image(extra='<input name="filtertype" type="string" value="nearest" />'),
                             BASE_FROM_IMG),
                   ["'img'", "filtertype", "'nearest'", "closest, linear, cubic"]),
    "through-nodegraph-interface": (_material(
        '  <nodegraph name="NG">\n    <input name="wrap" type="string" value="wrap" />\n'
        + _image(extra='<input name="vaddressmode" type="string" interfacename="wrap" />')
        + '\n    <output name="out" type="color3" nodename="img" />\n  </nodegraph>',
        '<input name="base_color" type="color3" nodegraph="NG" output="out" />'),
        ["'NG/img'", "vaddressmode", "'wrap'", "constant, clamp, periodic, mirror"]),
    "closure-string-enum": (_material(
        '  <dielectric_bsdf name="d" type="BSDF"><input name="scatter_mode" type="string" value="TR" />'
        "</dielectric_bsdf>", ""
    ).replace('<standard_surface name="SR" type="surfaceshader"></standard_surface>',
              '<surface name="SR" type="surfaceshader"><input name="bsdf" type="BSDF" nodename="d" /></surface>'),
        ["'d'", "scatter_mode", "'TR'", "R, T, RT"]),
}


@pytest.mark.parametrize("case", list(ENUM_CASES))
def test_enum_value_outside_the_nodedef_enum_is_an_input_error(case, tmp_path, capsys):
    doc, expected = ENUM_CASES[case]
    _texture(tmp_path)
    asset = tmp_path / "enum.mtlx"
    asset.write_text(doc)
    # compile (which inspect and conversion both run) refuses it ...
    with pytest.raises(InputError) as info:
        compile_material(mtlx_file.read_document(asset), "M")
    for s in [str(asset), *expected]:
        assert s in str(info.value), f"{s!r} not in {info.value}"
    # ... so inspect exits 2 instead of reporting OK.
    code, out, err = _inspect(capsys, asset)
    assert code == 2 and out == "" and err.startswith("mtlx2neural: error: ") and "Traceback" not in err
    assert str(asset) in err and expected[2] in err


def test_usduvtexture_black_wrap_is_accepted_and_reads_zero_outside(tmp_path):
    _texture(tmp_path)
    asset = tmp_path / "usdtex.mtlx"
    asset.write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n'
        '  <UsdUVTexture name="tx" type="multioutput" nodedef="ND_UsdUVTexture_23">\n'
        '    <input name="file" type="filename" value="tex.png" />\n'
        '    <input name="wrapS" type="string" value="black" />\n'
        '    <input name="wrapT" type="string" value="black" />\n  </UsdUVTexture>\n'
        '  <surface name="SR" type="surfaceshader"><input name="bsdf" type="BSDF" nodename="d" /></surface>\n'
        '  <oren_nayar_diffuse_bsdf name="d" type="BSDF">'
        '<input name="color" type="color3" nodename="tx" output="rgb" /></oren_nayar_diffuse_bsdf>\n'
        '  <surfacematerial name="M" type="material">\n'
        '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n'
        "  </surfacematerial>\n</materialx>\n")
    compiled = compile_material(mtlx_file.read_document(asset), "M")
    ev = compiled.evaluator
    key, inp, _ = next(p for p in compiled.varying_parameters() if p[0].endswith(".color"))
    env = ev.run(compiled.spatial_nodes, torch.tensor([[0.5, 0.5], [1.5, 0.5], [0.5, -0.5]]))
    color = ev.value(inp, env)
    torch.testing.assert_close(color[0], torch.full((3,), 0.5), atol=3e-3, rtol=0)  # 8-bit
    torch.testing.assert_close(color[1:], torch.zeros(2, 3))  # outside the image: black


# ----------------------------------------------------------------------------- 2. long chains

CHAIN = 600


def _chain_document(path: Path, n: int = CHAIN) -> None:
    """texcoord -> ``n`` chained ``add`` nodes (+0.001 in u each) -> convert -> base_color, in a nodegraph."""
    lines = ['  <nodegraph name="NG">', '    <texcoord name="a0" type="vector2" />']
    for i in range(1, n + 1):
        lines.append(f'    <add name="a{i}" type="vector2"><input name="in1" type="vector2" nodename="a{i - 1}" />'
                     f'<input name="in2" type="vector2" value="0.001, 0.0" /></add>')
    lines += [f'    <convert name="c" type="color3"><input name="in" type="vector2" nodename="a{n}" /></convert>',
              '    <output name="out" type="color3" nodename="c" />', "  </nodegraph>"]
    base = '<input name="base_color" type="color3" nodegraph="NG" output="out" />'
    path.write_text(_material("\n".join(lines), base))


def test_a_600_node_chain_compiles_evaluates_and_inspects(tmp_path, capsys):
    from mtlx2neural.reference.material import ReferenceMaterial

    asset = tmp_path / "chain.mtlx"
    _chain_document(asset)
    compiled = compile_material(mtlx_file.read_document(asset), "M")
    assert sum(n.category == "add" and n.path.startswith("NG/a") for n in compiled.graph.nodes) == CHAIN
    # The chain is spatial: evaluated per point, u + 600 * 0.001.
    ev = compiled.evaluator
    convert = next(i for i, n in enumerate(compiled.graph.nodes) if n.path == "NG/c")
    uv = torch.tensor([[0.1, 0.2], [0.3, 0.9]])
    env = ev.run(compiled.spatial_nodes, uv)
    # convert vector2 -> color3 pads the third channel with 0, as MaterialX's NG_convert_vector2_color3 does.
    torch.testing.assert_close(env[(convert, "out")], torch.tensor([[0.7, 0.2, 0.0], [0.9, 0.9, 0.0]]))
    # The reference BRDF evaluates it.
    wi = torch.tensor([[0.0, 0.6, 0.8], [0.6, 0.0, 0.8]])
    f = ReferenceMaterial(compiled).eval(wi, wi.flip(0), uv=uv)
    assert f.shape == (2, 3) and bool(torch.isfinite(f).all()) and bool((f > 0).all())
    code, out, err = _inspect(capsys, asset, "--json")
    assert code == 0, err
    assert json.loads(out)["materials"][0]["textures"] == []


def test_a_too_deep_closure_tree_is_an_input_error(tmp_path):
    from mtlx2neural.graph.bsdf_program import MAX_CLOSURE_DEPTH

    n = MAX_CLOSURE_DEPTH + 20
    lines = ['  <oren_nayar_diffuse_bsdf name="b0" type="BSDF" />']
    lines += [f'  <multiply name="b{i}" type="BSDF"><input name="in1" type="BSDF" nodename="b{i - 1}" />'
              f'<input name="in2" type="color3" value="0.99, 0.99, 0.99" /></multiply>' for i in range(1, n + 1)]
    doc = _material("\n".join(lines), "").replace(
        '<standard_surface name="SR" type="surfaceshader"></standard_surface>',
        f'<surface name="SR" type="surfaceshader"><input name="bsdf" type="BSDF" nodename="b{n}" /></surface>')
    asset = tmp_path / "deep.mtlx"
    asset.write_text(doc)
    with pytest.raises(InputError, match=rf"deep.mtlx: the closure tree is nested more than {MAX_CLOSURE_DEPTH}"):
        compile_material(mtlx_file.read_document(asset), "M")


# ----------------------------------------------------------------------------- 3. unreadable files


def _run_cli(prefix: list[str], *argv, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*prefix, sys.executable, "-m", "mtlx2neural.cli", *[str(a) for a in argv]],
                          capture_output=True, text=True, timeout=300, cwd=cwd, check=False)


def _write_unreadable_cases(folder: Path) -> dict[str, tuple[Path, Path]]:
    """id -> (asset to inspect, the file that is unreadable)."""
    (folder / "main.mtlx").write_text(SIMPLE_MTLX)
    (folder / "part.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n'
        '  <standard_surface name="SR" type="surfaceshader" />\n</materialx>\n')
    (folder / "includer.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39" xmlns:xi="http://www.w3.org/2001/XInclude">\n'
        '  <xi:include href="part.mtlx" />\n  <surfacematerial name="M" type="material">\n'
        '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n'
        "  </surfacematerial>\n</materialx>\n")
    (folder / "stage.usda").write_text('#usda 1.0\ndef Xform "World" {}\n')
    _texture(folder, "locked.png")
    (folder / "textured.mtlx").write_text(_material(_image(file="locked.png"), BASE_FROM_IMG))
    return {"mtlx": (folder / "main.mtlx", folder / "main.mtlx"),
            "xi-include": (folder / "includer.mtlx", folder / "part.mtlx"),
            "usd": (folder / "stage.usda", folder / "stage.usda"),
            "texture": (folder / "textured.mtlx", folder / "locked.png")}


# Runs ``inspect`` on each asset in one process (one interpreter start-up) and prints the results as JSON.
_INSPECT_EACH = """
import contextlib, io, json, sys
from mtlx2neural.cli import main
results = {}
for case, asset in json.loads(sys.argv[1]).items():
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["inspect", asset])
    results[case] = [code, out.getvalue(), err.getvalue()]
print(json.dumps(results))
"""


@pytest.mark.slow
def test_unreadable_files_are_reported_as_permission_denied(tmp_path):
    prefix = unprivileged_prefix(tmp_path)
    cases = _write_unreadable_cases(tmp_path)
    for _, locked in cases.values():  # each case reads only its own locked file
        locked.chmod(0)
    try:
        r = subprocess.run([*prefix, sys.executable, "-c", _INSPECT_EACH,
                            json.dumps({case: str(asset) for case, (asset, _) in cases.items()})],
                           capture_output=True, text=True, timeout=300, cwd=tmp_path, check=False)
    finally:
        for _, locked in cases.values():
            locked.chmod(0o644)
    assert r.returncode == 0, r.stderr
    results = json.loads(r.stdout)
    for case, (asset, locked) in cases.items():
        code, out, err = results[case]
        assert code == 2 and out == "" and "Traceback" not in err, f"{case}: exit {code}\n{err}"
        assert err.startswith("mtlx2neural: error: "), f"{case}: {err}"
        assert str(locked) in err and "permission denied" in err, f"{case}: {err}"
        assert "not found" not in err and "could not be found" not in err, f"{case}: {err}"
        if case == "xi-include":
            assert str(asset) in err  # names the including file too


# ----------------------------------------------------------------------------- 4. JSON stdout


@pytest.mark.slow
def test_inspect_json_stdout_is_json_when_openimageio_reports_errors(tmp_path):
    # A UDIM set (OpenImageIO cannot open the pattern itself) and a corrupt PNG used with
    # --allow-missing-textures: OpenImageIO used to print the unretrieved errors to stdout at exit.
    for tile in (1001, 1002):
        _texture(tmp_path, f"col.{tile}.png")
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"junk" * 10)
    asset = tmp_path / "textures.mtlx"
    asset.write_text(_material(_image("img", file="col.<UDIM>.png") + "\n" + _image("bad", file="corrupt.png"),
                               BASE_FROM_IMG + '<input name="specular_color" type="color3" nodename="bad" />'))
    r = _run_cli([], "inspect", asset, "--json", "--allow-missing-textures", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)  # nothing but the JSON document on stdout
    assert report["asset"] == str(asset)
    assert any("corrupt.png" in note for note in report["materials"][0]["approximations"])


def test_enum_lists_come_from_materialx_nodedefs():
    from mtlx2neural.graph.validate import allowed_values
    from mtlx2neural.scene.mxlib import nodedef

    nd = nodedef("ND_image_color3")
    assert allowed_values(nd.getActiveInput("uaddressmode")) == ["constant", "clamp", "periodic", "mirror"]
    assert allowed_values(nd.getActiveInput("file")) is None
    assert isinstance(nd, mx.NodeDef)
