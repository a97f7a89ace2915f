"""The codeless USD schema ``NeuralMaterialAPI`` and the Sdr ``NeuralBSDF`` shader.

Files (source of truth: the top-level ``schemas/`` folder of the repository):

- ``schemas/schema.usda``: the schema; ``generatedSchema.usda`` and
  ``plugInfo.json`` next to it are generated from it by :func:`regenerate`
  (``python -m pxr.Usd.usdGenSchema`` plus the placeholder replacement) and
  committed.
- ``schemas/shaders/NeuralBSDF.usda``: the Sdr shader definition, with the
  placeholder ``neural_bsdf.slang`` as its universal ``info:sourceAsset``.

In this process, call :func:`register` before USD's schema registry is first
used (``Usd.SchemaRegistry()``, also reached by opening or authoring a stage
with typed prims), because USD builds that registry once. Other processes
(usdview, DCCs) find the schema through
``PXR_PLUGINPATH_NAME=<plugin_path()>`` and the shader through
``PXR_SDR_FS_PLUGIN_SEARCH_PATHS=<shader_search_path()>`` with
``PXR_SDR_FS_PLUGIN_ALLOWED_EXTS=usda``; see :func:`environment`.

Packaging: a source checkout and the editable install (``pip install -e .``,
which imports ``mtlx2neural`` from the checkout) read ``schemas/`` at the
repository root. A wheel has no repository root, so ``setup.py`` copies
``schemas/`` into the built package as ``mtlx2neural/_schemas/`` (and
``MANIFEST.in`` puts ``schemas/`` into the sdist); :func:`plugin_path` looks
there first.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SCHEMA_NAME = "NeuralMaterialAPI"
"""Schema identifier, as used by ``prim.ApplyAPI`` and in ``apiSchemas``."""
SHADER_ID = "NeuralBSDF"
"""Sdr identifier and ``info:id`` of the neural BSDF shader."""

# Placeholders usdGenSchema leaves in plugInfo.json. The plugin is codeless
# (Type "resource", no library) and plugInfo.json sits next to
# generatedSchema.usda, so Root and ResourcePath are the folder itself.
PLUG_INFO_REPLACEMENTS = {
    "@PLUG_INFO_LIBRARY_PATH@": "",
    "@PLUG_INFO_RESOURCE_PATH@": ".",
    "@PLUG_INFO_ROOT@": ".",
}

_registered = False


def plugin_path() -> Path:
    """The folder holding ``plugInfo.json``, ``generatedSchema.usda`` and ``schema.usda``.

    ``mtlx2neural/_schemas`` inside an installed wheel, else ``schemas/`` at the
    root of the source checkout (editable installs). Raises FileNotFoundError
    when neither exists.
    """
    here = Path(__file__).resolve().parent
    for cand in (here / "_schemas", here.parent / "schemas"):
        if (cand / "plugInfo.json").is_file():
            return cand
    raise FileNotFoundError(f"mtlx2neural's USD schema plugin (plugInfo.json) is neither in {here / '_schemas'} "
                            f"nor in {here.parent / 'schemas'}; reinstall mtlx2neural")


def shader_search_path() -> Path:
    """The folder with the Sdr shader definition ``NeuralBSDF.usda`` (for PXR_SDR_FS_PLUGIN_SEARCH_PATHS)."""
    return plugin_path() / "shaders"


def environment(env: dict[str, str] | None = None) -> dict[str, str]:
    """``env`` (default ``os.environ``) copied, with the USD variables that expose the plugin.

    Prepends :func:`plugin_path` to ``PXR_PLUGINPATH_NAME`` and
    :func:`shader_search_path` to ``PXR_SDR_FS_PLUGIN_SEARCH_PATHS``, and adds
    ``usda`` to ``PXR_SDR_FS_PLUGIN_ALLOWED_EXTS`` (Sdr's filesystem discovery
    finds nothing without it). For launching usdview or a DCC as a subprocess.
    """
    env = dict(os.environ if env is None else env)

    def prepend(key: str, value: str, sep: str) -> None:
        items = [v for v in env.get(key, "").split(sep) if v]
        if value not in items:
            env[key] = sep.join([value] + items)

    prepend("PXR_PLUGINPATH_NAME", str(plugin_path()), os.pathsep)
    prepend("PXR_SDR_FS_PLUGIN_SEARCH_PATHS", str(shader_search_path()), os.pathsep)
    prepend("PXR_SDR_FS_PLUGIN_ALLOWED_EXTS", "usda", ":")
    return env


def register(shaders: bool = True) -> bool:
    """Register the schema plugin with USD, and the NeuralBSDF shader with Sdr; idempotent.

    Call before the first ``Usd.SchemaRegistry()`` use of the process (opening
    or authoring a stage with typed prims counts): USD builds the schema
    registry once, and a plugin registered later is not seen. ``shaders=True``
    also adds the ``NeuralBSDF`` definition to ``Sdr.Registry()`` (which
    initialises Sdr and, through its UsdShade discovery, the schema registry)
    unless Sdr already found it through ``PXR_SDR_FS_PLUGIN_SEARCH_PATHS``.

    Returns True when ``NeuralMaterialAPI`` is known to the schema registry,
    False (with a warning) when the registry was built before this call.
    """
    global _registered
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Plug, Tf, Usd

    if not _registered:
        Plug.Registry().RegisterPlugins(str(plugin_path()))
        if shaders:
            _register_shader()
        _registered = True
    ok = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(SCHEMA_NAME) is not None
    if not ok:
        Tf.Warn(f"{SCHEMA_NAME} is not in USD's schema registry: it was built before "
                "mtlx2neural.usd_schema.register() ran; call it earlier, or set "
                f"PXR_PLUGINPATH_NAME={plugin_path()}")
    return ok


def _register_shader() -> None:
    """Add NeuralBSDF.usda to Sdr, exactly as its filesystem discovery plugin would find it."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdr

    reg = Sdr.Registry()
    if SHADER_ID in reg.GetShaderNodeIdentifiers():
        return  # found through PXR_SDR_FS_PLUGIN_SEARCH_PATHS
    for result in Sdr.FsHelpersDiscoverShaderNodes([str(shader_search_path())], ["usda"], False):
        reg.AddDiscoveryResult(result)


def regenerate(out_dir: str | os.PathLike | None = None, schema: str | os.PathLike | None = None) -> Path:
    """Run usdGenSchema on ``schema`` (default: the package's ``schema.usda``) into ``out_dir``.

    Writes ``generatedSchema.usda`` and ``plugInfo.json`` with the
    ``@PLUG_INFO_*@`` placeholders replaced (:data:`PLUG_INFO_REPLACEMENTS`).
    ``out_dir`` defaults to the folder of ``schema``, i.e. regenerates the
    committed files in place. Needs jinja2. Runs in a subprocess so that this
    process's USD registries stay untouched. Returns ``out_dir``.
    """
    schema = Path(schema) if schema is not None else plugin_path() / "schema.usda"
    out = Path(out_dir) if out_dir is not None else schema.parent
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        # usdGenSchema reads and rewrites plugInfo.json if the output folder has one
        # (keeping hand edits); generate into an empty folder so the result depends
        # on schema.usda alone.
        proc = subprocess.run([sys.executable, "-m", "pxr.Usd.usdGenSchema", str(schema), tmp],
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"usdGenSchema failed:\n{proc.stdout}\n{proc.stderr}")
        text = (Path(tmp) / "plugInfo.json").read_text()
        for key, value in PLUG_INFO_REPLACEMENTS.items():
            text = text.replace(key, value)
        (out / "plugInfo.json").write_text(text)
        shutil.copyfile(Path(tmp) / "generatedSchema.usda", out / "generatedSchema.usda")
    return out


if __name__ == "__main__":  # python -m mtlx2neural.usd_schema: regenerate the committed files
    print(regenerate())
