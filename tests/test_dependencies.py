"""The default command paths import only core dependencies.

The README's quick start installs ``pip install -e .`` (no extras). A module that
``mtlx2neural ASSET``, ``inspect``, ``render`` or ``report`` imports without a
guard must therefore come from a distribution that the core dependencies in
``pyproject.toml`` pull in (directly or through their own requirements). This test
runs the four commands in a fresh interpreter, maps every imported top-level module
to its distribution, and fails on any distribution outside that closure (other
than the few optional ones imported under a guard, listed with the reason). It
caught ``flip-evaluator``, which every conversion needs and only an extra
installed. CI also runs the quick start itself in a fresh venv (``.ci/run``).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
from conftest import SIMPLE_MTLX

ROOT = Path(__file__).resolve().parents[1]

OPTIONAL_GUARDED = {
    # report: times the generated shaders on slangpy's CPU device when it is installed, and says
    # so in the report otherwise (mtlx2neural.codegen.cpu.slangpy_available).
    "slangpy": "shader timings in the report (optional: the 'shaders' extra)",
}

# Modules already loaded when the interpreter starts (site's .pth hooks, e.g. the cmeel wheels'
# cmeel_pth) are not imported by the commands, so they are left out of the record.
SCRIPT = r"""
import json, sys
started = {m.split(".")[0] for m in list(sys.modules)}
from mtlx2neural.cli import main
asset, out, layer, record = sys.argv[1:5]
codes = {
    "inspect": main(["inspect", asset, "--json"]),
    "convert": main([asset, "--iterations", "2", "--batch", "64", "--quiet", "--workers", "1", "--device", "cpu"]),
    "render": main(["render", asset, "--material", "Red", "--model", "neural", "--res", "8", "--spp", "1",
                    "-o", out]),
    "report": main(["report", layer, "--res", "8", "--spp", "1", "--analytic-iterations", "2"]),
}
modules = sorted({m.split(".")[0] for m in list(sys.modules)} - started)
with open(record, "w") as f:
    json.dump({"codes": codes, "modules": modules}, f)
"""


def _name(requirement: str) -> str:
    return re.split(r"[\s;<>=!~\[(]", requirement.strip(), maxsplit=1)[0].lower().replace("_", "-")


def core_closure() -> set[str]:
    """Distribution names the core dependencies pull in, transitively (extras' requirements excluded)."""
    import tomllib

    core = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    seen: set[str] = set()
    todo = [_name(r) for r in core]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            reqs = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        todo += [_name(r) for r in reqs if "extra" not in (r.split(";", 1)[1] if ";" in r else "")]
    return seen


@pytest.mark.slow
def test_the_default_commands_import_only_core_dependencies(tmp_path):
    if sys.version_info < (3, 11):
        pytest.skip("tomllib needs Python 3.11")
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    record = tmp_path / "record.json"
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(asset), str(tmp_path / "r.exr"),
                        str(tmp_path / "red_neural.usda"), str(record)],
                       capture_output=True, text=True, cwd=tmp_path, timeout=900, check=False)
    assert r.returncode == 0 and record.is_file(), r.stderr[-3000:]
    result = json.loads(record.read_text())
    assert result["codes"] == {"inspect": 0, "convert": 0, "render": 0, "report": 0}, r.stderr[-3000:]

    dists = metadata.packages_distributions()
    closure = core_closure() | {"mtlx2neural"}
    outside = {}
    for module in result["modules"]:
        if module in sys.stdlib_module_names or module.startswith("_"):
            continue
        for dist in dists.get(module, []):
            name = _name(dist)
            if name not in closure and module not in OPTIONAL_GUARDED:
                outside[module] = name
    assert not outside, (f"the default commands import modules that no core dependency installs: {outside}; "
                         f"add their distributions to [project] dependencies, or guard the import")
