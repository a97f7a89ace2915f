"""MaterialX documents shared by the tests, built from a few fragments instead of retyped XML.

``document(*fragments)`` wraps element fragments in a MaterialX 1.39 document;
``standard_surface(material, shader, **inputs)`` is a standard_surface node and the
surfacematerial over it; ``image(name, file, ...)`` is an image node. Input values are
typed from their Python form: a 3-tuple is a ``color3``, a number a ``float``, a string
naming another node (``node=...``) a connection.
"""

from __future__ import annotations

HEADER = '<?xml version="1.0"?>\n<materialx version="1.39">\n'
FOOTER = "</materialx>\n"


def _input(name: str, value) -> str:
    if isinstance(value, dict):  # {"node": "img"}: a connection (type from "type", default color3)
        return f'    <input name="{name}" type="{value.get("type", "color3")}" nodename="{value["node"]}" />\n'
    if isinstance(value, bool):
        return f'    <input name="{name}" type="boolean" value="{str(value).lower()}" />\n'
    if isinstance(value, tuple):
        return f'    <input name="{name}" type="color3" value="{", ".join(str(v) for v in value)}" />\n'
    return f'    <input name="{name}" type="float" value="{value}" />\n'


def standard_surface(material: str, shader: str = "SR", **inputs) -> str:
    """A standard_surface named ``shader`` with ``inputs`` and a surfacematerial ``material`` over it."""
    body = "".join(_input(k, v) for k, v in inputs.items())
    return (f'  <standard_surface name="{shader}" type="surfaceshader">\n{body}  </standard_surface>\n'
            f'  <surfacematerial name="{material}" type="material">\n'
            f'    <input name="surfaceshader" type="surfaceshader" nodename="{shader}" />\n'
            "  </surfacematerial>\n")


def image(name: str, file: str, type: str = "color3", colorspace: str | None = None) -> str:
    """An ``image`` node reading ``file`` (relative paths resolve against the document's folder)."""
    cs = f' colorspace="{colorspace}"' if colorspace else ""
    return (f'  <image name="{name}" type="{type}">\n'
            f'    <input name="file" type="filename" value="{file}"{cs} />\n  </image>\n')


def closure(material: str, category: str, node: str = "lobe") -> str:
    """A single pbrlib closure ``category`` under a surface and a surfacematerial ``material``."""
    return (f'  <{category} name="{node}" type="BSDF" />\n'
            '  <surface name="surf" type="surfaceshader">\n'
            f'    <input name="bsdf" type="BSDF" nodename="{node}" />\n  </surface>\n'
            f'  <surfacematerial name="{material}" type="material">\n'
            '    <input name="surfaceshader" type="surfaceshader" nodename="surf" />\n'
            "  </surfacematerial>\n")


def document(*fragments: str) -> str:
    """A MaterialX document holding ``fragments`` in order."""
    return HEADER + "".join(fragments) + FOOTER


def reference_of(*fragments: str, material: str = "M"):
    """The compiled reference BRDF (:class:`~mtlx2neural.reference.ReferenceMaterial`) of ``material`` in
    the document of ``fragments`` (read in memory, MaterialX's libraries beside it)."""
    import MaterialX as mx

    from mtlx2neural.graph import compile_material
    from mtlx2neural.graph.library import with_libraries
    from mtlx2neural.reference import ReferenceMaterial

    doc = mx.createDocument()
    mx.readFromXmlString(doc, document(*fragments))
    return ReferenceMaterial(compile_material(with_libraries(doc), material))


# A minimal valid material (a red standard_surface named Red); needs nothing from ../shared.
SIMPLE_MTLX = document(standard_surface("Red", "SR_red", base_color=(0.8, 0.1, 0.1)))

# Two materials sharing nothing.
TWO_MTLX = document(standard_surface("Red", "SR_red", base_color=(0.8, 0.1, 0.1)),
                    standard_surface("Blue", "SR_blue", base_color=(0.1, 0.1, 0.8), specular_roughness=0.6))

# A textured material whose only varying parameter is the base colour (albedo.png beside the document).
TEXTURED_MTLX = document(image("albedo", "albedo.png", colorspace="srgb_texture"),
                         standard_surface("Tex", "SR_tex", base_color={"node": "albedo"}, specular_roughness=0.4))

# A material whose only closure has no torch implementation (hair).
HAIR_MTLX = document(closure("M", "chiang_hair_bsdf", node="hair"))


def usd_painted_ball(shader_inputs: str, extra_shaders: str = "", metadata: str = "") -> str:
    """A USD layer: a Sphere ``/World/Ball`` bound to ``/World/Looks/Paint``, a MaterialX
    standard_surface network whose ``SR`` shader has ``shader_inputs`` (USD attribute lines)
    and whose other shaders are ``extra_shaders``; ``metadata`` is the layer's metadata block."""
    indent = " " * 16
    inputs = "".join(f"{indent}{line.strip()}\n" for line in shader_inputs.strip().splitlines())
    return (f"#usda 1.0\n{metadata}"
            'def Xform "World"\n{\n'
            '    def Sphere "Ball" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
            "        rel material:binding = </World/Looks/Paint>\n    }\n"
            '    def Scope "Looks"\n    {\n        def Material "Paint"\n        {\n'
            "            token outputs:mtlx:surface.connect = </World/Looks/Paint/SR.outputs:surface>\n"
            '            def Shader "SR"\n            {\n'
            '                uniform token info:id = "ND_standard_surface_surfaceshader"\n'
            f"{inputs}                token outputs:surface\n            }}\n"
            f"{extra_shaders}        }}\n    }}\n}}\n")


def usd_quad_reading_position(space: str = "object") -> str:
    """A USD layer: a 2 x 3 quad ``/World/Quad`` (uv (0,0)-(1,1) onto x in [0, 2], y in [0, 3], translated
    by (10, 0, 0)) bound to ``/World/Looks/M``, a standard_surface whose base_color is the ``position``
    node ``P`` in ``space`` (converted to a colour)."""
    return ('#usda 1.0\n(\n    metersPerUnit = 1\n)\ndef Xform "World"\n{\n'
            '    def Mesh "Quad" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
            '        double3 xformOp:translate = (10, 0, 0)\n'
            '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
            '        point3f[] points = [(0, 0, 0), (2, 0, 0), (2, 3, 0), (0, 3, 0)]\n'
            '        int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n'
            '        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")\n'
            '        rel material:binding = </World/Looks/M>\n    }\n'
            '    def Scope "Looks"\n    {\n        def Material "M"\n        {\n'
            '            token outputs:mtlx:surface.connect = </World/Looks/M/SR.outputs:surface>\n'
            '            def Shader "P"\n            {\n'
            '                uniform token info:id = "ND_position_vector3"\n'
            f'                string inputs:space = "{space}"\n                float3 outputs:out\n            }}\n'
            '            def Shader "C"\n            {\n'
            '                uniform token info:id = "ND_convert_vector3_color3"\n'
            '                float3 inputs:in.connect = </World/Looks/M/P.outputs:out>\n'
            '                color3f outputs:out\n            }\n'
            '            def Shader "SR"\n            {\n'
            '                uniform token info:id = "ND_standard_surface_surfaceshader"\n'
            '                color3f inputs:base_color.connect = </World/Looks/M/C.outputs:out>\n'
            '                token outputs:surface\n            }\n        }\n    }\n}\n')


def layered_spheres_material(name: str):
    """The bundled ``samples/layered_spheres.usda`` material ``/World/Looks/<name>`` (a uniform one:
    CarPaint or Plastic) as ``(reference, 1x1 parameter stack)``, ready for a Trainer."""
    # Local imports: the rest of this module writes documents and needs neither torch nor MaterialX.
    from pathlib import Path

    import mtlx2neural as m2n
    from mtlx2neural.textures.parameter_stack import build_parameter_stack

    ref = m2n.load_reference(Path(__file__).resolve().parents[1] / "samples" / "layered_spheres.usda",
                             f"/World/Looks/{name}")
    return ref, build_parameter_stack(ref.compiled, resolution=(1, 1))


def layered_spheres_trainers(names, folder, **overrides):
    """One :class:`~mtlx2neural.train.trainer.Trainer` per material of ``names`` (:func:`layered_spheres_material`),
    the ``fast`` preset with ``overrides``, each in ``folder/<name>``: a picklable factory for a row process."""
    from pathlib import Path

    from mtlx2neural.train.config import preset
    from mtlx2neural.train.trainer import Trainer

    cfg = preset("fast", **overrides)
    return [Trainer(*layered_spheres_material(n), cfg, Path(folder) / n) for n in names]


def broken_row_factory(how: str):
    """A row process's factory that fails: ``raise`` an error, or ``exit`` the process without an answer."""
    import os

    if how == "exit":
        os._exit(3)
    raise ValueError("this factory cannot prepare its materials")
