"""An OpenPBR copy of a Standard Surface document, to measure the universal open_pbr_surface network on real textures.

Run:  python benchmarks/openpbr_copy.py SRC.mtlx OUT_DIR

MaterialX ships no textured OpenPBR example, so this writes ``OUT_DIR/<stem>_openpbr.mtlx``: every
``standard_surface`` that the universal standard_surface network covers (its inputs beyond the opaque
reflection at their defaults) becomes an ``open_pbr_surface`` reading the same connections and values,
input for input (base -> base_weight, metalness -> base_metalness, specular -> specular_weight,
specular_IOR -> specular_ior, coat -> coat_weight, coat_IOR -> coat_ior, normal -> geometry_normal;
base_color, specular_color, specular_roughness, coat_color and coat_roughness keep their names). Its
emission is dropped and the other shaders are left as they are. The folders beside ``SRC`` are linked
into ``OUT_DIR``, so relative texture paths resolve; ``SRC`` is not modified.

The two models are not the same BRDF (OpenPBR's metal uses F82 tinting, its coat darkens the base), so the
copy is a different material with the same textures, not a translation.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import MaterialX as mx

from mtlx2neural.universal.canonical import eligibility

RENAMED = {"base": "base_weight", "metalness": "base_metalness", "specular": "specular_weight",
           "specular_IOR": "specular_ior", "coat": "coat_weight", "coat_IOR": "coat_ior", "normal": "geometry_normal"}
KEPT = ("base_color", "specular_color", "specular_roughness", "coat_color", "coat_roughness")


def openpbr_copy(src: Path, out_dir: Path) -> tuple[Path, list[str]]:
    """Write the copy (module docstring); returns its path and the materials whose shader was replaced."""
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(src))
    replaced = []
    for material in doc.getMaterialNodes():
        if eligibility(doc, material.getName()).model != "standard_surface":
            continue
        old = doc.getNode(material.getInput("surfaceshader").getNodeName())
        new = doc.addNode("open_pbr_surface", f"{old.getName()}_openpbr", "surfaceshader")
        for inp in old.getInputs():
            name = RENAMED.get(inp.getName(), inp.getName() if inp.getName() in KEPT else None)
            if name is None:
                continue
            copy = new.addInput(name, inp.getType())
            copy.copyContentFrom(inp)
        material.getInput("surfaceshader").setNodeName(new.getName())
        doc.removeNode(old.getName())
        replaced.append(material.getName())
    out_dir.mkdir(parents=True, exist_ok=True)
    for entry in src.parent.iterdir():  # relative texture paths resolve from the copy's folder
        link = out_dir / entry.name
        if entry.is_dir() and not link.exists():
            os.symlink(entry.resolve(), link)
    path = out_dir / f"{src.stem}_openpbr.mtlx"
    mx.writeToXmlFile(doc, str(path))
    return path, replaced


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", type=Path)
    p.add_argument("out_dir", type=Path)
    a = p.parse_args(argv)
    path, replaced = openpbr_copy(a.src, a.out_dir)
    print(f"{path}: {len(replaced)} material(s) on open_pbr_surface: {', '.join(replaced)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
