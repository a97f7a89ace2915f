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

A material that emits or is not opaque (its ``surface.json``, :mod:`.surface_files`) adds, only what it has::

      Shader SR_neural_<ident>        token inputs:edf.connect -> N_neural_<ident>_edf.outputs:out
                                      float inputs:opacity.connect -> N_neural_<ident>_cutout.outputs:out
                                        (mask), N_neural_<ident>_opacity.outputs:out (blend), or a constant
      Shader N_neural_<ident>_edf     info:id = "ND_uniform_edf"
                                      color3f inputs:color.connect -> N_neural_<ident>_emission.outputs:out,
                                        or the constant radiance
      Shader N_neural_<ident>_emission info:id = "ND_image_color3", asset inputs:file = @./.../emission.exr@,
                                      float2 inputs:texcoord.connect -> N_neural_<ident>_texcoord.outputs:out
      Shader N_neural_<ident>_opacity info:id = "ND_image_float", asset inputs:file = @./.../opacity.exr@,
                                      the same texcoord
      Shader N_neural_<ident>_cutout  info:id = "ND_ifgreatereq_float" (a mask only): value1 <- the opacity,
                                      value2 = the cutoff (0.5), in1 = 1, in2 = 0

as MaterialX's ``surface`` node shades them: colour = (reflected + emitted) * opacity, the mask
thresholded as MaterialX's own UsdPreviewSurface graph does (``ifgreatereq``, ``usd_preview_surface.mtlx``).
The nodes and their settings are those of the material's MaterialX document
(:func:`mtlx2neural.codegen.materialx_node.add_surface_nodes`, names from ``node_names``) as UsdMtlx would
read it: the image nodes wrap periodically (``uaddressmode`` / ``vaddressmode``, as the latents do), the
emission's ``file`` carries the colour space ``lin_rec709`` (as ``colorSpace`` metadata, UsdMtlx's form of
MaterialX's ``colorspace``), the opacity is data. A constant opacity is authored as a consumer uses it: a
mask's alpha-tested (0 or 1), a blend's clamped to [0, 1]. Unlike the document, which reads copies of the
maps beside it, the layer's image nodes read the export's ``emission.exr`` / ``opacity.exr`` themselves.

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
from mtlx2neural.textures.surface_maps import ALPHA_CUTOFF, used_opacity

SURFACE_ID = "ND_surface"
"""The nodedef of MaterialX's ``surface`` node (BSDF, EDF and opacity into a surface shader)."""
TEXCOORD_ID = "ND_geompropvalue_vector2"
"""MaterialX's primvar reader for a vector2 (``geomprop``: the primvar's name)."""
TEXCOORD_PRIMVAR = "st"
EDF_ID = "ND_uniform_edf"
"""MaterialX's uniformly emitting EDF (``color``: the radiance)."""
IMAGE_IDS = {"color3": "ND_image_color3", "float": "ND_image_float"}
"""MaterialX's image readers of the emission and the opacity map."""
CUTOUT_ID = "ND_ifgreatereq_float"
"""``value1 >= value2 ? in1 : in2``: the alpha test of a mask."""
EMISSION_COLORSPACE = "lin_rec709"
"""The emission map's colour space (:mod:`.surface_files`), stated on the image's ``file`` input."""


def _define_shader(stage, path):
    """A ``def Shader`` at ``path`` whose missing ancestors are authored as ``over``."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    prim = stage.OverridePrim(path)
    prim.SetSpecifier(Sdf.SpecifierDef)
    prim.SetTypeName("Shader")
    return UsdShade.Shader(prim)


def _image(stage, path, type_name, asset: str, texcoord):
    """An ``image`` node of ``type_name`` (``color3``: the emission, colour space ``lin_rec709``; ``float``:
    the opacity, data) reading ``asset`` at ``texcoord`` with periodic wrap; its output."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    t = Sdf.ValueTypeNames
    image = _define_shader(stage, path)
    image.CreateIdAttr(IMAGE_IDS[type_name])
    file = image.CreateInput("file", t.Asset)
    file.Set(Sdf.AssetPath(asset))
    if type_name == "color3":  # UsdMtlx's form of MaterialX's colorspace attribute on an input
        file.GetAttr().SetColorSpace(EMISSION_COLORSPACE)
    for axis in ("uaddressmode", "vaddressmode"):
        image.CreateInput(axis, t.String).Set("periodic")
    image.CreateInput("texcoord", t.Float2).ConnectToSource(texcoord)
    return image.CreateOutput("out", t.Color3f if type_name == "color3" else t.Float)


def _surface_terms(stage, material, n, surface_shader, surface: dict, texcoord) -> None:
    """Emission (``inputs:edf``) and opacity (``inputs:opacity``) of the ``ND_surface`` shader from
    ``surface`` (the manifest of :mod:`.surface_files`, files as the layer's asset paths); ``n``: the
    material's ``node_names``; module docstring."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Gf, Sdf

    t = Sdf.ValueTypeNames
    path = material.GetPath()
    emission, opacity = surface.get("emission"), surface.get("opacity")
    if emission:
        edf = _define_shader(stage, path.AppendChild(n.edf))
        edf.CreateIdAttr(EDF_ID)
        color = edf.CreateInput("color", t.Color3f)
        if "file" in emission:
            color.ConnectToSource(_image(stage, path.AppendChild(n.emission), "color3", emission["file"], texcoord))
        else:
            color.Set(Gf.Vec3f(*(float(x) for x in emission["constant"])))
        surface_shader.CreateInput("edf", t.Token).ConnectToSource(edf.CreateOutput("out", t.Token))
    if opacity:
        mask = surface.get("alpha_mode") == "mask"
        value = surface_shader.CreateInput("opacity", t.Float)
        if "file" not in opacity:
            value.Set(used_opacity(float(opacity["constant"]), surface.get("alpha_mode", "opaque")))
            return
        read = _image(stage, path.AppendChild(n.opacity), "float", opacity["file"], texcoord)
        if mask:
            cut = _define_shader(stage, path.AppendChild(n.cutout))
            cut.CreateIdAttr(CUTOUT_ID)
            cut.CreateInput("value1", t.Float).ConnectToSource(read)
            cut.CreateInput("value2", t.Float).Set(ALPHA_CUTOFF)
            cut.CreateInput("in1", t.Float).Set(1.0)
            cut.CreateInput("in2", t.Float).Set(0.0)
            read = cut.CreateOutput("out", t.Float)
        value.ConnectToSource(read)


def author_mtlx_network(stage, material, name: str, latent_assets: list[str], surface: dict | None = None):
    """Author the MaterialX network of material ``name`` (module docstring) under the UsdShade
    ``material`` at ``stage``'s edit target; ``latent_assets``: the latent textures' asset paths as the
    layer states them (relative to it), in channel order. ``surface``: the material's emission and opacity
    (the manifest of :func:`~mtlx2neural.export.surface_files.write_surface_files` with each ``file`` as
    the layer states it), or None. Returns the neural BSDF's Shader."""
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
    texcoord = reader.CreateOutput("out", t.Float2)
    bsdf.CreateInput("texcoord", t.Float2).ConnectToSource(texcoord)
    surface_shader = _define_shader(stage, path.AppendChild(n.surface))
    surface_shader.CreateIdAttr(SURFACE_ID)
    surface_shader.CreateInput("bsdf", t.Token).ConnectToSource(bsdf.CreateOutput("out", t.Token))
    if surface:
        _surface_terms(stage, material, n, surface_shader, surface, texcoord)
    material.CreateSurfaceOutput("mtlx").ConnectToSource(surface_shader.CreateOutput("surface", t.Token))
    return bsdf
