"""Build single-closure MaterialX documents for tests (real MaterialX documents, no mocks)."""

from __future__ import annotations

import MaterialX as mx

from mtlx2neural.graph import compile_material
from mtlx2neural.graph.library import standard_library
from mtlx2neural.reference import ReferenceMaterial


def _value(mx_type, v):
    if mx_type == "color3":
        return mx.Color3(*v)
    if mx_type == "vector3":
        return mx.Vector3(*v)
    if mx_type == "vector2":
        return mx.Vector2(*v)
    return v


def closure_document(category: str, **inputs) -> mx.Document:
    """``category`` (a pbrlib BSDF) -> surface -> surfacematerial 'M', with ``inputs`` set."""
    doc = mx.createDocument()
    node = doc.addNode(category, "lobe", "BSDF")
    nodedef = standard_library().getMatchingNodeDefs(category)[0]
    for name, value in inputs.items():
        mx_type = nodedef.getActiveInput(name).getType()
        node.setInputValue(name, _value(mx_type, value), mx_type)
    surf = doc.addNode("surface", "surf", "surfaceshader")
    surf.setConnectedNode("bsdf", node)
    doc.addMaterialNode("M", surf)
    return doc


def closure_material(category: str, **inputs) -> ReferenceMaterial:
    return ReferenceMaterial(compile_material(closure_document(category, **inputs), "M"))
