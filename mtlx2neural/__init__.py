"""mtlx2neural: bake MaterialX materials into real-time neural appearance models.

Public API (see DESIGN.md):

>>> import mtlx2neural as m2n
>>> m = m2n.load_reference("asset.usda", material="/World/Looks/Brass")
>>> m.eval(wi, wo)   # [N,3] f * cos
"""

from __future__ import annotations

__version__ = "0.1.0"


def load_reference(path, material: str | None = None, device: str = "cpu", allow_missing_textures: bool = False):
    """Load ``material`` from a ``.mtlx`` file or a USD stage and compile its reference BRDF.

    ``material`` is a USD material prim path (or prim name) or a MaterialX
    surfacematerial name; it may be omitted when the asset selects exactly one.
    ``allow_missing_textures`` substitutes an image node's declared ``default`` for a
    missing file instead of failing.
    Returns a :class:`mtlx2neural.reference.ReferenceMaterial`.
    """
    from .graph import compile_material
    from .reference import ReferenceMaterial
    from .scene import find_material

    src = find_material(path, material)
    compiled = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures)
    compiled.name = src.name
    return ReferenceMaterial(compiled)


__all__ = ["load_reference", "__version__"]
