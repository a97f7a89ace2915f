"""The package layering: every import points down the data flow.

``LAYERS`` lists the top-level components of ``mtlx2neural`` from the bottom up. A module
may import from its own component and from components in lower rows only; components
in one row must not import each other. The test walks every ``import`` statement in the
package (module level and function local alike) with :mod:`ast`, so it fails on the
first new upward import, and it also bounds module length and asks for a reason beside
each function-local import.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "mtlx2neural"

LAYERS: list[tuple[str, ...]] = [
    ("version",),
    ("errors",),
    ("faults",),
    ("file_lock",),
    ("atomic",),
    ("progress",),
    ("staging",),
    ("contract",),
    ("usd_schema",),
    ("formats",),  # FP16 and the weights file: below both export and codegen
    ("imaging",),
    ("scene",),
    ("graph",),
    ("reference",),
    ("textures",),
    ("model",),
    ("train",),
    ("render", "oracle", "verify"),
    ("codegen",),
    ("baseline",),
    ("export",),
    ("pipeline",),
    ("report",),
    ("api",),
    ("commands",),
    ("cli",),
    ("__init__",),  # the package itself: the public entry points
]
RANK = {name: i for i, row in enumerate(LAYERS) for name in row}
MAX_LINES = 600


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        yield path, rel.parts[0].removesuffix(".py")


def _imports(path: Path):
    """(line, imported component, is function-local, has a reason comment) for every mtlx2neural import."""
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    # imports under `if TYPE_CHECKING:` are for annotations only and count as module level
    for node in tree.body:
        if isinstance(node, ast.If):
            top.update(id(n) for n in node.body)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}:{node.lineno}: use absolute imports (mtlx2neural.<package>...)"
            names = [node.module or ""]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] != "mtlx2neural":
                continue
            target = parts[1] if len(parts) > 1 else "__init__"
            if target == "__init__" and isinstance(node, ast.ImportFrom):
                # `from mtlx2neural import x`: x is a module (a component) or a public name
                sub = node.names[0].name
                target = sub if sub in RANK else "__init__"
            context = " ".join(lines[max(0, node.lineno - 3): node.lineno])
            yield node.lineno, target, id(node) not in top, "#" in context


def test_every_component_has_a_layer():
    missing = sorted({comp for _, comp in _modules()} - set(RANK))
    assert not missing, f"add these components of mtlx2neural/ to LAYERS: {missing}"


def test_imports_point_down_the_data_flow():
    upward = []
    for path, comp in _modules():
        for line, target, _, _ in _imports(path):
            if target == comp:
                continue
            if RANK[target] >= RANK[comp]:
                upward.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({comp}) imports {target}")
    assert not upward, "imports that run up (or across) the layering:\n" + "\n".join(upward)


def test_function_local_imports_say_why():
    silent = []
    for path, _ in _modules():
        for line, _, local, reason in _imports(path):
            if local and not reason:
                silent.append(f"{path.relative_to(PACKAGE.parent)}:{line}")
    assert not silent, "function-local imports without a comment saying why:\n" + "\n".join(silent)


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_modules_stay_small(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.name} has {n} lines; split it by concept (limit {MAX_LINES})"


def test_the_layering_check_catches_an_upward_import(tmp_path):
    """The walker itself: an upward import in a scratch module is reported with its target."""
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from mtlx2neural.pipeline.plan import DECODERS\n    return DECODERS\n")
    found = list(_imports(probe))
    assert found == [(2, "pipeline", True, False)]
    assert RANK["pipeline"] > RANK["graph"]
