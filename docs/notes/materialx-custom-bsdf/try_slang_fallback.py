"""Does genslang fall back to the genglsl implementation (targetdef genslang inherits genglsl)?"""
import os, MaterialX as mx
import MaterialX.PyMaterialXGenSlang as mx_slang
from gen import load_doc, make_context, HERE
doc, lib, ok, msg = load_doc("neural_material.mtlx")
doc.removeChild("IM_myneural_bsdf_genslang")       # keep only the genglsl implementation
gen = mx_slang.SlangShaderGenerator.create()
ctx = make_context(gen)
sh = gen.generate("M_neural", doc.getNode("M_neural"), ctx)
open(os.path.join(HERE, "out", "M_neural_slang_from_glsl_pixel.slang"), "w").write(sh.getSourceCode("pixel"))
open(os.path.join(HERE, "out", "M_neural_slang_from_glsl_vertex.slang"), "w").write(sh.getSourceCode("vertex"))
print("generated genslang shader from the genglsl implementation")
