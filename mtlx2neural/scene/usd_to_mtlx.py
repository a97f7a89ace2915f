"""A UsdShade material network -> a self-contained MaterialX document.

Layout of the produced document
-------------------------------
* One ``surfacematerial`` node named after the Material prim.
* One node per Shader prim reached from the surface terminal, at the top level
  of the document. NodeGraph prims are **flattened**: connections are followed
  through NodeGraph outputs, NodeGraph interface inputs and Material interface
  inputs (``UsdShadeInput.GetValueProducingAttributes``) down to the shader
  output or authored value that actually produces each input. Node names come
  from the prim path relative to the Material (``NG_brass1/image_color`` ->
  ``NG_brass1_image_color``); each node's ``doc`` string holds the prim path
  and its ``nodedef`` attribute the nodedef that ``info:id`` names.
* Input types come from the MaterialX nodedef. Inputs without a connection or
  an authored value are left out, so the nodedef default applies.
* Asset values become absolute paths (relative to the layer that authored
  them); ``colorSpace`` metadata becomes the input's ``colorspace``.
* Where USD connects an output to an input of another MaterialX type (e.g. a
  texture's ``rgb`` (color3) into a ``normal`` (vector3)), a ``convert`` node
  is inserted, because MaterialX does not allow implicit conversions.
* USD-native UsdPreviewSurface-family ids are mapped to MaterialX's own
  nodedefs for them (see ``usd_preview``).

Only the surface terminal is converted (``outputs:mtlx:surface`` preferred,
else the universal ``outputs:surface``); displacement and volume terminals are
ignored because the neural model is a reflectance model.
"""

from __future__ import annotations

import MaterialX as mx
from pxr import Sdf, Usd, UsdShade

from mtlx2neural.errors import InputError
from mtlx2neural.scene import mxlib, usd_preview
from mtlx2neural.scene.usd_values import (
    ValueConversionError,
    authored_value,
    resolve_asset,
    to_value_string,
)

MTLX_CONTEXT = "mtlx"


def defining_file(prim: Usd.Prim) -> str:
    """Path of the layer that defines ``prim`` (its strongest ``def``), for messages."""
    for spec in prim.GetPrimStack():
        if spec.specifier == Sdf.SpecifierDef:
            layer = spec.layer
            return layer.realPath or layer.identifier
    root = prim.GetStage().GetRootLayer()
    return root.realPath or root.identifier


def convert_material(material: UsdShade.Material, source_file: str | None = None) -> tuple["mx.Document", str]:
    """Convert the UsdShade network of ``material`` into a MaterialX document.

    Returns ``(document, surfacematerial node name)``. The document holds only
    the network (no standard-library content). Raises InputError when the
    Material has no surface terminal, a shader's ``info:id`` is not a
    MaterialX nodedef, or an input/value/connection does not fit the nodedef.
    """
    source_file = source_file or defining_file(material.GetPrim())
    return _Converter(material, source_file).run()


class _Converter:
    def __init__(self, material: UsdShade.Material, source_file: str):
        self.material = material
        self.mat_path = material.GetPath()
        self.source_file = source_file
        self.doc = mx.createDocument()
        self.doc.setColorSpace("lin_rec709")
        self.doc.setSourceUri(source_file)  # so later stages' messages name the file
        self.nodes: dict[Sdf.Path, mx.Node] = {}
        self.nodedefs: dict[str, mx.NodeDef] = {}
        self.converts: dict[tuple[str, str, str], mx.Node] = {}

    def _where(self, prim_path=None) -> str:
        path = prim_path if prim_path is not None else self.mat_path
        return f"{self.source_file}: <{path}>"

    # -- terminal -----------------------------------------------------------
    def run(self) -> tuple["mx.Document", str]:
        shader = self._surface_shader()
        mat_name = self._unique(mx.createValidName(self.mat_path.name))
        mat_node = self.doc.addNode("surfacematerial", mat_name, "material")
        mat_node.setDocString(str(self.mat_path))
        node = self._node_for(shader.GetPrim())
        nd = self.nodedefs[node.getName()]
        if mxlib.node_type(nd) != "surfaceshader":
            raise InputError(
                f"{self._where()}: the surface terminal connects to <{shader.GetPath()}> "
                f"({nd.getName()}), whose output type is {mxlib.node_type(nd)}, not surfaceshader. "
                "Connect the Material's surface output to a surface shader."
            )
        inp = mat_node.addInput("surfaceshader", "surfaceshader")
        inp.setNodeName(node.getName())
        return self.doc, mat_name

    def _surface_shader(self) -> UsdShade.Shader:
        shader, _, _ = self.material.ComputeSurfaceSource(MTLX_CONTEXT)
        if shader and shader.GetPrim().IsValid():
            return shader
        terminals = [o.GetFullName() for o in self.material.GetOutputs()]
        found = ", ".join(terminals) if terminals else "none"
        raise InputError(
            f"{self._where()}: the Material has no surface terminal connected to a shader "
            f"(looked for outputs:mtlx:surface and outputs:surface; outputs present: {found}). "
            "Connect outputs:mtlx:surface (MaterialX) or outputs:surface (UsdPreviewSurface) to a shader."
        )

    # -- nodes --------------------------------------------------------------
    def _node_name(self, path: Sdf.Path) -> str:
        if path.HasPrefix(self.mat_path) and path != self.mat_path:
            rel = str(path.MakeRelativePath(self.mat_path))
        else:
            rel = str(path).lstrip("/")
        return self._unique(mx.createValidName(rel.replace("/", "_")))

    def _unique(self, base: str) -> str:
        """``base``, suffixed if needed so that it clashes with neither the document nor the libraries.

        (USD exports often name shader prims after their nodedef, e.g.
        ``ND_standard_surface_surfaceshader``; such a node would shadow the
        nodedef once the libraries are imported next to it.)
        """
        lib = mxlib.standard_library()
        name, i = base, 1
        while self.doc.getChild(name) is not None or lib.getChild(name) is not None:
            name = f"{base}_{i}"
            i += 1
        return name

    def _node_for(self, prim: Usd.Prim) -> "mx.Node":
        path = prim.GetPath()
        if path in self.nodes:
            return self.nodes[path]
        shader = UsdShade.Shader(prim)
        shader_id = shader.GetShaderId() or ""
        if not shader_id:
            raise InputError(
                f"{self._where(path)}: the shader has no info:id. "
                "Set info:id to a MaterialX nodedef name (e.g. ND_standard_surface_surfaceshader) "
                "or a UsdPreviewSurface-family id."
            )
        nd_name, native = usd_preview.nodedef_name(shader_id)
        nd = mxlib.nodedef(nd_name)
        if nd is None:
            raise InputError(
                f"{self._where(path)}: info:id {shader_id!r} is not a nodedef in the MaterialX "
                f"{mx.getVersionString()} standard libraries. Use a MaterialX nodedef name "
                "(e.g. ND_standard_surface_surfaceshader, ND_image_color3) or a UsdPreviewSurface-family id."
            )
        node = self.doc.addNode(nd.getNodeString(), self._node_name(path), mxlib.node_type(nd))
        node.setNodeDefString(nd.getName())
        node.setDocString(str(path))
        self.nodes[path] = node
        self.nodedefs[node.getName()] = nd
        for usd_input in shader.GetInputs():
            if native and usd_input.GetBaseName() in usd_preview.CONSUMED_INPUTS.get(shader_id, ()):
                continue
            self._set_input(node, nd, shader_id, native, usd_input)
        if native and shader_id == "UsdUVTexture":
            self._texture_color_space(node, shader)
        return node

    # -- inputs -------------------------------------------------------------
    def _set_input(self, node, nd, shader_id: str, native: bool, usd_input: UsdShade.Input) -> None:
        name = usd_input.GetBaseName()
        prim_path = usd_input.GetPrim().GetPath()
        nd_input = nd.getActiveInput(name)
        if nd_input is None:
            valid = ", ".join(i.getName() for i in nd.getActiveInputs())
            raise InputError(
                f"{self._where(prim_path)}: input {name!r} is not an input of the MaterialX nodedef "
                f"{nd.getName()} (info:id {shader_id!r}). Valid inputs: {valid}. Remove or rename it."
            )
        mx_type = nd_input.getType()
        sources = usd_input.GetValueProducingAttributes(shaderOutputsOnly=False)
        if not sources:
            return
        attr = sources[0]
        if UsdShade.Output.IsOutput(attr):
            upstream = attr.GetPrim()
            if not upstream.IsA(UsdShade.Shader):
                return  # dangling NodeGraph output: nodedef default applies
            up_node = self._node_for(upstream)
            src_node, src_output = self._source(up_node, UsdShade.Output(attr).GetBaseName(), mx_type, prim_path, name)
            inp = node.addInput(name, mx_type)
            inp.setNodeName(src_node.getName())
            if src_output:
                inp.setOutputString(src_output)
            return
        value = authored_value(attr)
        if value is None:
            return
        if native:
            value = usd_preview.translate_value(shader_id, name, value)
        inp = node.addInput(name, mx_type)
        if mx_type == "filename":
            asset = value if isinstance(value, Sdf.AssetPath) else Sdf.AssetPath(str(value))
            inp.setValueString(resolve_asset(attr, asset))
            color_space = usd_preview.mx_color_space(attr.GetColorSpace() or "")
            if color_space and not native:
                inp.setColorSpace(color_space)
            return
        try:
            text = to_value_string(value, mx_type, nd_input.getAttribute("enum"), nd_input.getAttribute("enumvalues"))
        except ValueConversionError as exc:
            raise InputError(
                f"{self._where(prim_path)}: input {name!r} of {nd.getName()}: the value {value!r} "
                f"(from <{attr.GetPath()}>) does not fit MaterialX type {mx_type}: {exc}. "
                "Author a value of the nodedef's type."
            ) from exc
        inp.setValueString(text)

    def _source(self, up_node, usd_output: str, in_type: str, prim_path, input_name: str):
        """The (node, output name or "") feeding an input of type ``in_type``; adds a convert node if needed."""
        up_nd = self.nodedefs[up_node.getName()]
        outputs = mxlib.output_types(up_nd)
        if len(outputs) == 1:
            out_name, out_type = "", next(iter(outputs.values()))
        elif usd_output in outputs:
            out_name, out_type = usd_output, outputs[usd_output]
        else:
            raise InputError(
                f"{self._where(prim_path)}: input {input_name!r} connects to output {usd_output!r} of "
                f"<{up_node.getDocString()}> ({up_nd.getName()}), which has no such output. "
                f"Its outputs are: {', '.join(outputs)}."
            )
        if out_type == in_type:
            return up_node, out_name
        key = (up_node.getName(), out_name, in_type)
        if key in self.converts:
            return self.converts[key], ""
        conv_nd = mxlib.nodedef(f"ND_convert_{out_type}_{in_type}")
        if conv_nd is None:
            raise InputError(
                f"{self._where(prim_path)}: input {input_name!r} has MaterialX type {in_type} but is connected "
                f"to <{up_node.getDocString()}> output of type {out_type}, and MaterialX has no conversion "
                "between them. Connect an output of a matching type."
            )
        base = f"{up_node.getName()}_{out_name or 'out'}_to_{in_type}"
        conv = self.doc.addNode("convert", self._unique(base), in_type)
        conv.setNodeDefString(conv_nd.getName())
        conv_in = conv.addInput("in", out_type)
        conv_in.setNodeName(up_node.getName())
        if out_name:
            conv_in.setOutputString(out_name)
        self.nodedefs[conv.getName()] = conv_nd
        self.converts[key] = conv
        return conv, ""

    def _texture_color_space(self, node, shader: UsdShade.Shader) -> None:
        file_input = node.getInput("file")
        if file_input is None or not file_input.getValueString():
            return
        source_cs = "auto"
        usd_cs = shader.GetInput("sourceColorSpace")
        if usd_cs:
            attrs = usd_cs.GetValueProducingAttributes(shaderOutputsOnly=False)
            if attrs and not UsdShade.Output.IsOutput(attrs[0]):
                source_cs = str(authored_value(attrs[0]) or "auto")
        asset_cs = ""
        usd_file = shader.GetInput("file")
        if usd_file:
            attrs = usd_file.GetValueProducingAttributes(shaderOutputsOnly=False)
            if attrs and not UsdShade.Output.IsOutput(attrs[0]):
                asset_cs = attrs[0].GetColorSpace() or ""
        cs = usd_preview.texture_color_space(source_cs, asset_cs, file_input.getValueString())
        if cs:
            file_input.setColorSpace(cs)
