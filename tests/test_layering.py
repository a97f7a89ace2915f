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
import sys
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
    ("material_record",),  # summary.json: the typed record every later stage reads
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
    ("universal",),  # shading models' universal networks: trained like a material, fitted into by the pipeline
    ("render", "oracle", "verify"),
    ("codegen",),
    ("baseline",),
    ("export",),
    ("pipeline",),
    ("report",),
    ("mitsuba",),  # optional: Mitsuba 3 plugins and scenes, over the export and the report's scene
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


def _parse(path: Path):
    """(source lines, AST, ids of the module-level statements). Imports under ``if TYPE_CHECKING:`` are
    for annotations only and count as module level."""
    source = path.read_text()
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    for node in tree.body:
        if isinstance(node, ast.If):
            top.update(id(n) for n in node.body)
    return source.splitlines(), tree, top


def _imports(path: Path):
    """(line, imported component, is function-local, has a reason comment) for every mtlx2neural import."""
    lines, tree, top = _parse(path)
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


def _third_party_local_imports(path: Path):
    """(line, module, has a reason comment) for every function-local import of a module outside the
    standard library and mtlx2neural. A comment counts when it sits on the import's line or on the
    lines just above the run of import statements the import belongs to."""
    lines, tree, top = _parse(path)
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Import, ast.ImportFrom)) or id(node) in top:
            continue
        module = (node.module or "") if isinstance(node, ast.ImportFrom) else node.names[0].name
        root = module.split(".")[0]
        if root in ("mtlx2neural", "") or root in sys.stdlib_module_names:
            continue
        first = node.lineno - 1
        while first > 0 and lines[first - 1].strip().startswith(("import ", "from ")):
            first -= 1
        context = lines[max(0, first - 2): node.lineno]
        yield node.lineno, module, any("#" in text for text in context)


def test_function_local_imports_say_why():
    silent = []
    for path, _ in _modules():
        for line, _, local, reason in _imports(path):
            if local and not reason:
                silent.append(f"{path.relative_to(PACKAGE.parent)}:{line}")
        for line, module, reason in _third_party_local_imports(path):
            if not reason:
                silent.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({module})")
    assert not silent, ("function-local imports without a comment saying why (move a third-party import to "
                        "the top unless importing it late matters):\n" + "\n".join(silent))


def test_the_local_import_check_wants_a_reason(tmp_path):
    """The walker itself: a silent local third-party import is found, a commented block is not."""
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    import numpy\n\n\ndef g():\n    # Local: a reason.\n    import numpy\n"
                     "    import torch\n    import pxr.Usd\n    import os\n")
    assert [(line, reason) for line, _, reason in _third_party_local_imports(probe)] == \
        [(2, False), (7, True), (8, True), (9, True)]


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


def _module_graph() -> dict[str, set[str]]:
    """Module name -> the mtlx2neural modules it imports (anywhere in it). ``from pkg import mod``
    counts as importing ``pkg.mod``, not the package's ``__init__``."""
    mods = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        mods[".".join(rel.parts).removesuffix(".__init__")] = path
    graph = {m: set() for m in mods}
    for m, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mtlx2neural"):
                subs = [f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in mods]
                names = subs if len(subs) == len(node.names) else [node.module, *subs]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            graph[m] |= {n for n in names if n in mods and n != m}
    return graph


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles (strongly connected sets of two or more modules) among edges that stay
    inside one component (``mtlx2neural.<component>``)."""
    def component(m: str) -> str:
        return m.split(".")[1] if "." in m else ""

    order, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        order[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if component(w) != component(v):
                continue
            if w not in order:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], order[w])
        if low[v] == order[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in order:
            visit(v)
    return found


def test_no_import_circles_inside_a_package():
    circles = _circles(_module_graph())
    assert not circles, "modules that import each other (directly or around a circle):\n" + "\n".join(
        " <-> ".join(c) for c in circles)


def test_the_circle_check_finds_a_circle():
    graph = {"mtlx2neural.a.x": {"mtlx2neural.a.y"}, "mtlx2neural.a.y": {"mtlx2neural.a.z"},
             "mtlx2neural.a.z": {"mtlx2neural.a.x"}, "mtlx2neural.b.w": {"mtlx2neural.a.x"},
             "mtlx2neural.a.v": {"mtlx2neural.b.w"}}
    assert _circles(graph) == [["mtlx2neural.a.x", "mtlx2neural.a.y", "mtlx2neural.a.z"]]
