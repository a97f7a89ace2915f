"""The neural material as a MaterialX network in the USD layer, in the shape UsdMtlx gives MaterialX documents.

In the ``neural`` variant of each converted Material (:mod:`.usd_writer`), for the material's
``NeuralMaterial_<ident>.mtlx`` (:func:`mtlx2neural.codegen.materialx_node.write_materialx_node`)::

    Material  outputs:mtlx:surface.connect -> SR_neural_<ident>.outputs:surface
      Shader SR_neural_<ident>        info:id = "ND_surface"
                                      token inputs:bsdf.connect -> N_neural_<ident>.outputs:out
      Shader N_neural_<ident>         info:id = "ND_neural_<ident>_bsdf" (the material's nodedef)
                                      asset inputs:latent<k> = @./.../latent_atlas_<k>.exr@  (relative to the layer)
                                      float2 inputs:texcoord.connect -> N_neural_<ident>_texcoord.outputs:out
      Shader N_neural_<ident>_texcoord info:id = "ND_geompropvalue_vector2", inputs:geomprop = "st"

UsdMtlx reads a MaterialX document into this shape: one Shader per node, whose ``info:id`` is
the node's *nodedef name* (``ND_...``), not its category, ``filename`` inputs as ``asset`` inputs,
and the Material's ``outputs:mtlx:surface`` connected to the surface shader's ``outputs:surface``
(see the ``usdcat --flatten`` of usdMtlx-read documents in usd-wg/assets,
``test_assets/MaterialXTest/basicTextured_flatten.usda``: ``info:id =
"ND_standard_surface_surfaceshader"``, ``asset inputs:file``). Hydra's hdMtlx rebuilds the
MaterialX document from these ids, so a viewer must find the nodedef, and its ``genglsl``
implementation file, through its MaterialX search path: ``PXR_MTLX_PLUGIN_SEARCH_PATHS`` (folders
of custom ``.mtlx`` definitions, read by UsdMtlx's Sdr discovery and hdMtlx) must list every
folder holding a ``NeuralMaterial_<ident>.mtlx``; ``PXR_MTLX_STDLIB_SEARCH_PATHS`` is only needed
when the viewer's USD build does not find MaterialX's standard libraries itself (OpenUSD
``usdMtlx/utils.h`` and ``hdMtlx/hdMtlx.h`` document both variables). The texture coordinates
are read explicitly from the primvar ``st`` (MaterialX's primvar reader, ``geompropvalue``)
rather than left to the nodedef's default geometric property ``UV0``, whose primvar name
depends on the viewer's settings.
"""

from __future__ import annotations

from mtlx2neural.codegen.materialx_node import node_names

SURFACE_ID = "ND_surface"
"""The nodedef of MaterialX's ``surface`` node (BSDF, EDF and opacity into a surface shader)."""
TEXCOORD_ID = "ND_geompropvalue_vector2"
"""MaterialX's primvar reader for a vector2 (``geomprop``: the primvar's name)."""
TEXCOORD_PRIMVAR = "st"


def _define_shader(stage, path):
    """A ``def Shader`` at ``path`` whose missing ancestors are authored as ``over``."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    prim = stage.OverridePrim(path)
    prim.SetSpecifier(Sdf.SpecifierDef)
    prim.SetTypeName("Shader")
    return UsdShade.Shader(prim)


def author_mtlx_network(stage, material, name: str, latent_assets: list[str]):
    """Author the MaterialX network of material ``name`` (module docstring) under the UsdShade
    ``material`` at ``stage``'s edit target; ``latent_assets``: the latent textures' asset paths as the
    layer states them (relative to it), in channel order. Returns the neural BSDF's Shader."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    t = Sdf.ValueTypeNames
    n = node_names(name)
    path = material.GetPath()
    bsdf = _define_shader(stage, path.AppendChild(n.node))
    bsdf.CreateIdAttr(n.nodedef)
    for k, asset in enumerate(latent_assets):
        bsdf.CreateInput(f"latent{k}", t.Asset).Set(Sdf.AssetPath(asset))
    reader = _define_shader(stage, path.AppendChild(f"{n.node}_texcoord"))
    reader.CreateIdAttr(TEXCOORD_ID)
    reader.CreateInput("geomprop", t.String).Set(TEXCOORD_PRIMVAR)
    bsdf.CreateInput("texcoord", t.Float2).ConnectToSource(reader.CreateOutput("out", t.Float2))
    surface = _define_shader(stage, path.AppendChild(n.surface))
    surface.CreateIdAttr(SURFACE_ID)
    surface.CreateInput("bsdf", t.Token).ConnectToSource(bsdf.CreateOutput("out", t.Token))
    material.CreateSurfaceOutput("mtlx").ConnectToSource(surface.CreateOutput("surface", t.Token))
    return bsdf
