"""Slang shader code for trained neural materials (docs/ARCHITECTURE.md, "codegen: the shader side").

- :func:`generate_slang`: the per-material module ``NeuralMaterial_<name>.slang`` (FP32,
  divergent FP16, coherent CoopVec and cooperative-matrix CoopMat variants) from a model or an
  export folder;
- :func:`write_material_shader`: that module plus its weight binaries and the runtime, into an
  export folder;
- :mod:`.cpu`: run generated modules on slangpy's CPU device (tests, benchmarks);
- :mod:`.compile`: compile them to HLSL / SPIR-V with ``slangc`` and validate the result;
- :mod:`.engine`: the HLSL and SPIR-V files the export ships for engines without Slang.

The runtime (``NeuralMaterial.slang``, ``NeuralLayers.slang``) and the templates are in the
top-level ``codegen/`` folder (see :mod:`.paths`).
"""

from mtlx2neural.codegen.generate import generate_slang, identifier
from mtlx2neural.codegen.paths import codegen_path, runtime_path
from mtlx2neural.codegen.spec import NetworkSpec, as_spec
from mtlx2neural.codegen.weight_layout import coopmat_blob, coopvec_blob, fp16_blob
from mtlx2neural.codegen.write import write_material_shader

__all__ = ["NetworkSpec", "as_spec", "codegen_path", "coopmat_blob", "coopvec_blob", "fp16_blob", "generate_slang", "identifier",
           "runtime_path", "write_material_shader"]
