"""Where the shader runtime and templates live (the top-level ``codegen/`` folder).

A source checkout and the editable install read ``codegen/`` at the repository root; a wheel
has it as ``mtlx2neural/_codegen`` (``setup.py`` copies it, ``MANIFEST.in`` puts it into the
sdist), which is looked at first, as :func:`mtlx2neural.usd_schema.plugin_path` does for the
schemas.
"""

from __future__ import annotations

from pathlib import Path

RUNTIME_FILES = ("NeuralMaterial.slang", "NeuralLayers.slang")
"""The runtime modules that every generated material module imports."""


def codegen_path() -> Path:
    """The folder holding ``slang/`` (runtime), ``templates/`` and ``examples/``."""
    here = Path(__file__).resolve().parent.parent
    for cand in (here / "_codegen", here.parent / "codegen"):
        if (cand / "slang" / RUNTIME_FILES[0]).is_file():
            return cand
    raise FileNotFoundError(f"mtlx2neural's shader runtime ({RUNTIME_FILES[0]}) is neither in "
                            f"{here / '_codegen' / 'slang'} nor in {here.parent / 'codegen' / 'slang'}; "
                            f"reinstall mtlx2neural")


def runtime_path() -> Path:
    """The folder of the runtime modules: the include path for generated modules."""
    return codegen_path() / "slang"


def examples_path() -> Path:
    return codegen_path() / "examples"


def template(name: str) -> str:
    """The text of ``codegen/templates/<name>``."""
    return (codegen_path() / "templates" / name).read_text()
