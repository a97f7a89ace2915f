"""Write a material's shader files next to its exported weights.

Files written into ``folder`` (the export's ``<material>/neural/``)::

    NeuralMaterial_<name>.slang          the generated module (imports the two below)
    NeuralMaterial_<name>.fp16.bin       FP16 weights in access order (``*_FP16Buffer`` variant)
    NeuralMaterial_<name>.coopvec.bin    row-major FP16 matrices and biases (coherent path; the
                                         module's header lists their offsets, shapes and strides)
    NeuralMaterial_<name>.coopmat.bin    FP16 matrices padded to the 16x16 tiles and biases
                                         (cooperative-matrix path, ``coopmat_blob``)
    NeuralMaterial.slang, NeuralLayers.slang   copies of the runtime modules

each written atomically, so that the folder compiles on its own (``slangc -I <folder>`` or
Slang's default search of the importing file's folder). :func:`~.engine.write_engine_files` adds the HLSL and
SPIR-V that engines without Slang include.

The module's ``<prefix>_Surface`` (emission and opacity) binds ``emission.exr`` / ``opacity.exr`` of the
folder when the material has them (its ``surface.json``, which the export writes first).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from mtlx2neural.atomic import atomic_path
from mtlx2neural.codegen.generate import generate_slang, identifier
from mtlx2neural.codegen.paths import RUNTIME_FILES, runtime_path
from mtlx2neural.codegen.spec import as_spec, read_surface_spec, surface_spec
from mtlx2neural.codegen.weight_layout import coopmat_blob, coopvec_blob, fp16_blob


def write_material_shader(model_or_export, folder, name: str, *, coherent: bool = True) -> list[Path]:
    """Generate and write the shader files of one material into ``folder``; returns their paths.

    The module's emission and opacity (``<prefix>_Surface``) follow ``folder``'s ``surface.json``
    (the export writes the maps first), else those of ``model_or_export`` (an export folder's
    ``surface.json`` or a model's ``surface``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    spec = as_spec(model_or_export)
    surface = read_surface_spec(folder) or surface_spec(model_or_export)
    stem = f"NeuralMaterial_{identifier(name)}"
    written = []

    def put(fname: str, data) -> None:
        path = folder / fname
        with atomic_path(path) as tmp:
            tmp.write_bytes(data if isinstance(data, bytes) else data.encode())
        written.append(path)

    put(f"{stem}.slang", generate_slang(spec, name, coherent=coherent, source=f"material {name}", surface=surface))
    put(f"{stem}.fp16.bin", fp16_blob(spec)[0])
    put(f"{stem}.coopvec.bin", coopvec_blob(spec)[0])
    put(f"{stem}.coopmat.bin", coopmat_blob(spec)[0])
    for f in RUNTIME_FILES:
        shutil.copyfile(runtime_path() / f, folder / f)
        written.append(folder / f)
    return written
