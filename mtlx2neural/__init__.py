"""mtlx2neural: bake MaterialX materials into real-time neural appearance models.

Public API (see docs/ARCHITECTURE.md):

>>> import mtlx2neural as m2n
>>> m = m2n.load_reference("asset.usda", material="/World/Looks/Brass")
>>> m.eval(wi, wo)   # [N,3] f * cos
>>> n = m2n.load_neural("asset_neural.usda", material="/World/Looks/Brass")  # the same methods

Converting from a pipeline (a DCC's open ``Usd.Stage``, unsaved edits included, or a file):

>>> from mtlx2neural.pipeline.options import ConvertOptions
>>> result = m2n.convert(stage, ConvertOptions(out="/shots/s010/neural"))
>>> result.layer, result.layer_path, result.summaries, result.skipped
"""

from __future__ import annotations

from mtlx2neural.version import __version__


def load_reference(path, material: str | None = None, device: str = "cpu", allow_missing_textures: bool = False,
                   frame: float = 1.0, fps: float = 24.0):
    """Load ``material`` from a ``.mtlx`` file or a USD stage and compile its reference BRDF.

    ``material`` is a USD material prim path (or prim name) or a MaterialX
    surfacematerial name; it may be omitted when the asset selects exactly one.
    ``allow_missing_textures`` substitutes an image node's declared ``default`` for a
    missing file instead of failing. ``frame``/``fps``: the instant MaterialX's ``frame`` and ``time``
    nodes fold to (``frame``, and ``frame / fps`` seconds), as ``convert``'s ``--frame``/``--fps``.
    Returns a :class:`mtlx2neural.reference.ReferenceMaterial`.
    """
    # Local: `import mtlx2neural` stays cheap (no torch, USD or MaterialX) until an entry point runs.
    from mtlx2neural.graph.ops import Application
    from mtlx2neural.reference.loading import load_reference as _load

    return _load(path, material, device, allow_missing_textures, Application(frame=float(frame), fps=float(fps)))


def usd_plugin_path() -> str:
    """Folder of mtlx2neural's USD schema plugin (``plugInfo.json`` of the codeless ``NeuralMaterialAPI``).

    Put it on ``PXR_PLUGINPATH_NAME`` (``os.pathsep``-separated) so that usdview
    or a DCC knows ``NeuralMaterialAPI`` in assets mtlx2neural exports:

        export PXR_PLUGINPATH_NAME="$(python -c 'import mtlx2neural; print(mtlx2neural.usd_plugin_path())')"

    Without it such assets still open and their materials still work: the
    schema is applied to a standard ``Material``. The Sdr ``NeuralBSDF`` shader
    definition is in its ``shaders/`` subfolder, found through
    ``PXR_SDR_FS_PLUGIN_SEARCH_PATHS=<that folder>`` together with
    ``PXR_SDR_FS_PLUGIN_ALLOWED_EXTS=usda``
    (:func:`mtlx2neural.usd_schema.environment` builds all three). Inside a
    Python process, :func:`mtlx2neural.usd_schema.register` registers both
    without environment variables, if called before USD's schema registry is
    first used.
    """
    # Local: keeps `import mtlx2neural` cheap.
    from mtlx2neural.usd_schema import plugin_path

    return str(plugin_path())


def load_neural(path, material: str | None = None, device: str = "cpu"):
    """Load ``material`` from a neural USD layer that ``mtlx2neural ASSET`` wrote (``ASSET_neural.usda``).

    The model is rebuilt from the layer's ``NeuralMaterialAPI`` attributes, the weights
    manifest and binary and the latent EXRs alone (not the training checkpoint); it has
    the reference's methods (``eval``, ``sample``, ``pdf``, ``albedo``, ``describe``) and
    reproduces the trained model to FP16 precision. ``material`` is the Material prim
    path or name (or the MaterialX material name for a ``.mtlx`` input); it may be
    omitted when the layer holds one neural material.
    Returns a :class:`mtlx2neural.export.load.ExportedNeuralMaterial`.
    """
    # Local: keeps `import mtlx2neural` cheap.
    from mtlx2neural.export.load import load_neural as _load

    return _load(path, material, device)


def convert(stage_or_path, options=None):
    """Convert the materials of an open ``Usd.Stage`` (session-layer and unsaved edits included) or of
    a USD or ``.mtlx`` file into neural materials, and write the neural USD layer.

    ``options``: a :class:`mtlx2neural.pipeline.options.ConvertOptions` (None: the defaults; an
    in-memory stage needs ``out``). Returns a :class:`mtlx2neural.api.ConversionResult`: ``layer``
    (the neural ``Sdf.Layer``), ``layer_path``, ``folder``, ``summaries``, ``skipped`` and ``failed``. See
    :func:`mtlx2neural.api.convert`.
    """
    # Local: keeps `import mtlx2neural` cheap (no torch, USD or MaterialX until a conversion runs).
    from mtlx2neural.api import convert as _convert

    return _convert(stage_or_path, options)


__all__ = ["__version__", "convert", "load_neural", "load_reference", "usd_plugin_path"]
