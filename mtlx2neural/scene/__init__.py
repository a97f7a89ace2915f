"""Scene stage: find the materials a scene's renderable geometry uses, as MaterialX documents.

Input is a ``.mtlx`` file or a USD stage. USD materials are either UsdShade
networks (MaterialX nodedef ids, or the UsdPreviewSurface family mapped onto
MaterialX's own nodedefs for it) or references to ``.mtlx`` files, which are
read directly because usd-core has no usdMtlx plugin. Each material is handed
on as a self-contained MaterialX document without the standard libraries.

Modules: ``loader`` (entry points), ``materials`` (result types, choosing by
name), ``mtlx_file``, ``usd_stage``, ``usd_to_mtlx``, ``usd_values``,
``usd_preview``, ``mtlx_refs``, ``binding``, ``mxlib``, ``mesh_digest`` (the bound meshes' data for the cache keys), ``texel_density`` (metres of
surface per UV unit of a material's meshes, for ``--texel-density``), ``uv_raster`` (the bound
meshes in UV space), ``stage_render`` (the bound meshes, camera and lights for the in-scene render).
"""

from mtlx2neural.scene.loader import find_material, load_asset
from mtlx2neural.scene.materials import MaterialSource, SceneMaterials

__all__ = ["MaterialSource", "SceneMaterials", "find_material", "load_asset"]
