"""An OpenPBR or glTF PBR copy of a Standard Surface document, to measure a universal network on real textures.

Run:  python benchmarks/model_copy.py SRC.mtlx OUT_DIR [--model open_pbr_surface|gltf_pbr]

MaterialX ships no textured OpenPBR or glTF PBR example, so this writes ``OUT_DIR/<stem>_<model>.mtlx``:
every ``standard_surface`` that the universal standard_surface network covers (its inputs beyond the
opaque reflection at their defaults) becomes a shader of ``model`` reading the same connections and
values, input for input (:data:`RENAMED`). An input the source leaves at Standard Surface's default is
written with that default, since the models' defaults differ (glTF's metallic and roughness are 1).
glTF PBR has no base weight: a ``base`` other than 1 multiplies ``base_color`` (a ``multiply`` node);
its coat is white with an IOR of 1.5, so ``coat_color`` and ``coat_IOR`` are dropped. Emission is
dropped and the other shaders are left as they are. The folders beside ``SRC`` are linked into
``OUT_DIR``, so relative texture paths resolve; ``SRC`` is not modified.

The models are not the same BRDF (OpenPBR's metal uses F82 tinting and its coat darkens the base; glTF's
metal is a Schlick one), so the copy is a different material with the same textures, not a translation.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import MaterialX as mx

from mtlx2neural.scene import mxlib
from mtlx2neural.universal.canonical import eligibility

RENAMED = {
    "open_pbr_surface": {"base": "base_weight", "base_color": "base_color", "metalness": "base_metalness",
                         "specular": "specular_weight", "specular_color": "specular_color",
                         "specular_roughness": "specular_roughness", "specular_IOR": "specular_ior",
                         "coat": "coat_weight", "coat_color": "coat_color", "coat_roughness": "coat_roughness",
                         "coat_IOR": "coat_ior", "normal": "geometry_normal"},
    "gltf_pbr": {"base_color": "base_color", "metalness": "metallic", "specular_roughness": "roughness",
                 "specular": "specular", "specular_color": "specular_color", "specular_IOR": "ior",
                 "coat": "clearcoat", "coat_roughness": "clearcoat_roughness", "normal": "normal"},
}
"""Per target model: Standard Surface input -> the target's input."""


def _copy_input(src: mx.Input | None, default: mx.Input, node, name: str) -> None:
    """Write ``src`` (or, unauthored, Standard Surface's ``default``) as ``node``'s input ``name``."""
    if src is None:
        if default.getValueString():  # a geometric default (normal): leave the target's own
            node.setInputValue(name, default.getValue())
        return
    node.addInput(name, src.getType()).copyContentFrom(src)


def _base_weight(doc: mx.Document, old, new, default: mx.Input) -> None:
    """glTF: ``base_color`` times a ``base`` other than 1 (connected or authored)."""
    base = old.getInput("base") or default
    if not (base.getNodeName() or base.getNodeGraphString()) and base.getValue() == 1.0:
        return
    mul = doc.addNode("multiply", f"{new.getName()}_base", "color3")
    mul.addInput("in1", "color3").copyContentFrom(new.getInput("base_color"))
    mul.addInput("in2", "float").copyContentFrom(base)
    new.removeInput("base_color")
    new.addInput("base_color", "color3").setNodeName(mul.getName())


def model_copy(src: Path, out_dir: Path, model: str = "open_pbr_surface") -> tuple[Path, list[str]]:
    """Write the copy (module docstring); returns its path and the materials whose shader was replaced."""
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(src))
    defaults = mxlib.nodedef("ND_standard_surface_surfaceshader")
    replaced = []
    for material in doc.getMaterialNodes():
        if eligibility(doc, material.getName()).model != "standard_surface":
            continue
        old = doc.getNode(material.getInput("surfaceshader").getNodeName())
        new = doc.addNode(model, f"{old.getName()}_{model}", "surfaceshader")
        for ss, name in RENAMED[model].items():
            _copy_input(old.getInput(ss), defaults.getActiveInput(ss), new, name)
        if model == "gltf_pbr":
            _base_weight(doc, old, new, defaults.getActiveInput("base"))
        material.getInput("surfaceshader").setNodeName(new.getName())
        doc.removeNode(old.getName())
        replaced.append(material.getName())
    out_dir.mkdir(parents=True, exist_ok=True)
    for entry in src.parent.iterdir():  # relative texture paths resolve from the copy's folder
        link = out_dir / entry.name
        if entry.is_dir() and not link.exists():
            os.symlink(entry.resolve(), link)
    path = out_dir / f"{src.stem}_{model}.mtlx"
    mx.writeToXmlFile(doc, str(path))
    return path, replaced


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", type=Path)
    p.add_argument("out_dir", type=Path)
    p.add_argument("--model", choices=sorted(RENAMED), default="open_pbr_surface",
                   help="shading model of the copy (default: %(default)s)")
    a = p.parse_args(argv)
    path, replaced = model_copy(a.src, a.out_dir, a.model)
    print(f"{path}: {len(replaced)} material(s) on {a.model}: {', '.join(replaced)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
