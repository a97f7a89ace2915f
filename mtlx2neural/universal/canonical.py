"""A shading model's canonical form: every input a universal encoder reads, present and varying.

A universal encoder (:mod:`mtlx2neural.universal`) is trained once over a shading model's parameter
space and reads the parameter stack of any material of that model. The stack's channels are the
compiled BSDF program's leaf parameters, and the compiler folds what is constant: a material with
``metallic`` 0 loses its metal lobe, one without a coat its coat lobe, so two materials of one model
can compile to different leaves. :func:`canonical_document` removes that difference. It rewrites the
material's shader so each of the model's :attr:`ShadingModel.varying` inputs is spatial: a connected
input keeps its connection, and an authored or default value ``c`` becomes ``c + 0 * texcoord.x``,
which the evaluator cannot fold (it classifies by dependence, not by value). Every material of the
model then compiles to one program, whose BRDF equals the original's: the rewrite adds zero.

:func:`canonical_names` strips the shader's own name from the parameter names (``SR_brass1<ND_...>/
metalness_metal_bsdf.roughness`` -> ``metalness_metal_bsdf.roughness``), so stacks of two materials of
the model compare channel by channel.
"""

from __future__ import annotations

from dataclasses import dataclass

import MaterialX as mx

PREFIX = "m2n_canonical_"


@dataclass(frozen=True)
class ShadingModel:
    """A shading model that a universal encoder covers."""

    category: str
    """The shader node's MaterialX category (``UsdPreviewSurface``)."""
    nodedef: str
    """Its surfaceshader nodedef, whose defaults fill unauthored inputs."""
    varying: tuple[str, ...]
    """The inputs the encoder reads, made varying in the canonical form; the others stay as authored
    (emission and opacity live beside the latents; displacement and occlusion are not reflectance)."""
    fixed: dict
    """Inputs that must keep these constant values (a switch between two programs), else the material
    is not of this model's canonical form: a colour as a tuple of floats; None, unset (not authored)."""
    neutral: dict
    """Parameters a material's canonical form may add that the atlas's folds away, with the value at which
    they change nothing: ``transmission_mix.mix`` 1 (the opaque lobes alone) appears when ``opacity`` is
    connected, since the graph's cut-out switch depends on it without changing the BRDF. A material holding
    another value there is not covered."""
    normal_map: str = ""
    """The varying input that is a world-space normal (``standard_surface``'s ``normal``): an unconnected one
    becomes a ``normalmap`` of the flat tangent-space normal, spatial, which is the geometric normal. Empty:
    the model's normal is itself a tangent-space vector (UsdPreviewSurface), made spatial like any value."""


SHADING_MODELS = {
    "UsdPreviewSurface": ShadingModel(
        "UsdPreviewSurface", "ND_UsdPreviewSurface_surfaceshader",
        ("diffuseColor", "metallic", "roughness", "clearcoat", "clearcoatRoughness", "ior", "normal"),
        {"useSpecularWorkflow": 0}, {"transmission_mix.mix": (1.0,)}),
    # Autodesk Standard Surface's opaque reflection: diffuse, metal, specular and coat. The rest, off in most
    # production materials (the chess set's pieces: 11 of 15), must hold its default.
    "standard_surface": ShadingModel(
        "standard_surface", "ND_standard_surface_surfaceshader",
        ("base", "base_color", "metalness", "specular", "specular_color", "specular_roughness", "specular_IOR",
         "coat", "coat_color", "coat_roughness", "coat_IOR", "normal"),
        {"diffuse_roughness": 0.0, "specular_anisotropy": 0.0, "transmission": 0.0, "subsurface": 0.0, "sheen": 0.0,
         "coat_anisotropy": 0.0, "coat_affect_color": 0.0, "coat_affect_roughness": 0.0, "thin_film_thickness": 0.0,
         "thin_walled": False, "coat_normal": None, "tangent": None}, {}, normal_map="normal"),
    # OpenPBR Surface's opaque reflection, as for Standard Surface: the base (diffuse and metal), specular and coat.
    "open_pbr_surface": ShadingModel(
        "open_pbr_surface", "ND_open_pbr_surface_surfaceshader",
        ("base_weight", "base_color", "base_metalness", "specular_weight", "specular_color", "specular_roughness",
         "specular_ior", "coat_weight", "coat_color", "coat_roughness", "coat_ior", "geometry_normal"),
        {"base_diffuse_roughness": 0.0, "specular_roughness_anisotropy": 0.0, "transmission_weight": 0.0,
         "subsurface_weight": 0.0, "fuzz_weight": 0.0, "coat_roughness_anisotropy": 0.0, "coat_darkening": 1.0,
         "thin_film_weight": 0.0, "geometry_thin_walled": False, "geometry_coat_normal": None,
         "geometry_tangent": None, "geometry_coat_tangent": None}, {}, normal_map="geometry_normal"),
    # glTF PBR (metallic-roughness, with KHR_materials_specular, _ior and _clearcoat): the diffuse, metal, specular
    # and coat lobes. Transmission, volume, iridescence, sheen and anisotropy must be off; alpha and emission live
    # beside the latents, and occlusion is not reflectance.
    "gltf_pbr": ShadingModel(
        "gltf_pbr", "ND_gltf_pbr_surfaceshader",
        ("base_color", "metallic", "roughness", "specular", "specular_color", "ior", "clearcoat",
         "clearcoat_roughness", "normal"),
        {"transmission": 0.0, "thickness": 0.0, "dispersion": 0.0, "iridescence": 0.0, "sheen_color": (0.0, 0.0, 0.0),
         "anisotropy_strength": 0.0, "clearcoat_normal": None, "tangent": None}, {}, normal_map="normal"),
}


@dataclass
class Eligibility:
    """Whether a material can take a universal encoder: its model's name, or why not (``reason``)."""

    model: str | None
    shader: str | None = None
    reason: str = ""


def _surface_shader(document: mx.Document, material: str | None):
    mats = [m for m in document.getMaterialNodes() if material in (None, m.getName())]
    if not mats:
        return None
    inp = mats[0].getInput("surfaceshader")
    name = inp.getNodeName() if inp is not None else ""
    return document.getNode(name) if name else None


def _connected(inp: mx.Input) -> bool:
    return bool(inp.getNodeName() or inp.getNodeGraphString() or inp.getOutputString() or inp.getInterfaceName())


def eligibility(document: mx.Document, material: str | None = None) -> Eligibility:
    """The shading model of ``material``'s surface shader when a universal encoder covers it (its
    category is a :data:`SHADING_MODELS` key and its :attr:`~ShadingModel.fixed` inputs hold their
    values); else ``model`` None and the reason."""
    shader = _surface_shader(document, material)
    if shader is None:
        return Eligibility(None, reason="no surface shader node at the document's top level")
    model = SHADING_MODELS.get(shader.getCategory())
    if model is None:
        return Eligibility(None, shader.getName(), f"shader '{shader.getName()}' is a {shader.getCategory()}, "
                                                   f"not one of {', '.join(SHADING_MODELS)}")
    for name, value in model.fixed.items():
        inp = shader.getInput(name)
        if inp is not None and (_connected(inp) or _value(inp) != value):
            held = "set" if value is None else f"not {value}"
            return Eligibility(None, shader.getName(), f"shader '{shader.getName()}': {name} is {held} "
                                                       f"(the universal encoder covers that program only)")
    if model.category == "UsdPreviewSurface" and _transparent(shader):
        return Eligibility(None, shader.getName(), f"shader '{shader.getName()}' is transparent (opacity below 1 "
                                                   f"without a cut-out threshold): its transmission is not covered")
    return Eligibility(model.category, shader.getName())


def _value(inp: mx.Input):
    """An input's value, a colour or vector as a tuple of floats (``fixed``'s form)."""
    value = inp.getValue()
    return tuple(float(x) for x in value) if hasattr(value, "__len__") and not isinstance(value, str) else value


def _transparent(shader) -> bool:
    """A UsdPreviewSurface whose opacity mixes in transmission: an opacity below 1 (or connected) with
    ``opacityThreshold`` 0, its default (a threshold above 0 makes opacity a cut-out beside the BRDF)."""
    threshold, opacity = shader.getInput("opacityThreshold"), shader.getInput("opacity")
    if threshold is not None and (_connected(threshold) or (threshold.getValue() or 0.0) > 0.0):
        return False
    return opacity is not None and (_connected(opacity) or opacity.getValue() < 1.0)


def _zero_node(doc: mx.Document) -> str:
    """A float node worth 0 everywhere that the evaluator treats as spatial: texcoord.x * 0."""
    name = f"{PREFIX}zero"
    if doc.getNode(name) is None:
        uv = doc.addNode("texcoord", f"{PREFIX}uv", "vector2")
        x = doc.addNode("extract", f"{PREFIX}u", "float")
        x.setConnectedNode("in", uv)
        x.setInputValue("index", 0)
        zero = doc.addNode("multiply", name, "float")
        zero.setConnectedNode("in1", x)
        zero.setInputValue("in2", 0.0)
    return name


def _flat_normal_map(doc: mx.Document) -> str:
    """A ``normalmap`` node of the flat tangent-space normal, made spatial: the geometric normal, as a value."""
    name = f"{PREFIX}normal_map"
    if doc.getNode(name) is None:
        flat = doc.addNode("add", f"{PREFIX}flat_normal", "vector3")
        flat.addInput("in1", "vector3").setValueString("0.5, 0.5, 1.0")
        flat.addInput("in2", "float").setNodeName(_zero_node(doc))
        nmap = doc.addNode("normalmap", name, "vector3")
        nmap.addInput("in", "vector3").setNodeName(flat.getName())
    return name


def canonical_document(document: mx.Document, material: str | None = None) -> mx.Document:
    """A copy of ``document`` whose ``material``'s shader has every varying input of its model spatial
    (module docstring); ``ValueError`` when the material is not eligible (:func:`eligibility`)."""
    elig = eligibility(document, material)
    if elig.model is None:
        raise ValueError(elig.reason)
    model = SHADING_MODELS[elig.model]
    from mtlx2neural.scene import mxlib  # the nodedef's defaults

    nodedef = mxlib.nodedef(model.nodedef)
    doc = mx.createDocument()
    doc.copyContentFrom(document)
    shader = doc.getNode(elig.shader)
    for name in model.varying:
        inp = shader.getInput(name)
        if inp is not None and _connected(inp):
            continue
        decl = nodedef.getActiveInput(name)
        value_string = inp.getValueString() if inp is not None and inp.getValueString() else decl.getValueString()
        mx_type = decl.getType()
        if inp is not None:
            shader.removeInput(name)
        if name == model.normal_map:
            shader.addInput(name, mx_type).setNodeName(_flat_normal_map(doc))
            continue
        add = doc.addNode("add", f"{PREFIX}{name}", mx_type)
        add.addInput("in1", mx_type).setValueString(value_string)
        add.addInput("in2", "float").setNodeName(_zero_node(doc))
        shader.addInput(name, mx_type).setNodeName(add.getName())
    return doc


def canonical_name(parameter: str) -> str:
    """A compiled parameter's name without its shader's path (the part after the last ``>/``)."""
    return parameter.rsplit(">/", 1)[-1]


def canonical_names(names) -> list[str]:
    return [canonical_name(n) for n in names]
