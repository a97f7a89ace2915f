"""Validate the custom-node documents and generate GLSL / Slang shaders (no hand edits)."""
import os, sys, MaterialX as mx
import MaterialX.PyMaterialXGenShader as mx_gen
import MaterialX.PyMaterialXGenGlsl as mx_glsl
import MaterialX.PyMaterialXGenSlang as mx_slang

HERE = os.path.dirname(os.path.abspath(__file__))
LIBROOT = os.path.dirname(mx.__file__)               # .../MaterialX  (contains libraries/)

def load_doc(material_file):
    stdlib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), stdlib)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, os.path.join(HERE, material_file))
    mx.readFromXmlFile(doc, os.path.join(HERE, "myneural_defs.mtlx"))   # custom nodedef + impls
    doc.setDataLibrary(stdlib)   # (doc.importLibrary(stdlib) also works)
    ok, msg = doc.validate()
    return doc, stdlib, ok, msg

def make_context(gen, env_method=mx_gen.SPECULAR_ENVIRONMENT_FIS):
    ctx = mx_gen.GenContext(gen)
    sp = mx.getDefaultDataSearchPath()          # finds libraries/pbrlib/genglsl/... includes
    sp.append(mx.FilePath(HERE))                # finds myneural_bsdf.glsl / .slang
    ctx.registerSourceCodeSearchPath(sp)
    o = ctx.getOptions()
    o.hwSpecularEnvironmentMethod = env_method
    o.fileTextureVerticalFlip = True            # GL texture origin is bottom-left
    o.hwMaxActiveLightSources = 1
    o.hwShadowMap = False
    o.targetColorSpaceOverride = "lin_rec709"
    return ctx

def generate(doc, gen, ctx, name):
    mat = doc.getNode(name)
    return gen.generate(mat.getName(), mat, ctx)

if __name__ == "__main__":
    os.makedirs(os.path.join(HERE, "out"), exist_ok=True)
    for f, m in [("neural_material.mtlx", "M_neural"), ("reference_material.mtlx", "M_reference")]:
        doc, lib, ok, msg = load_doc(f)
        print(f, "validate:", ok, msg.strip())
        for tag, gen, meth in [("glsl_fis", mx_glsl.GlslShaderGenerator.create(), mx_gen.SPECULAR_ENVIRONMENT_FIS),
                               ("glsl_prefilter", mx_glsl.GlslShaderGenerator.create(), mx_gen.SPECULAR_ENVIRONMENT_PREFILTER),
                               ("slang_fis", mx_slang.SlangShaderGenerator.create(), mx_gen.SPECULAR_ENVIRONMENT_FIS)]:
            ctx = make_context(gen, meth)
            try:
                sh = generate(doc, gen, ctx, m)
            except Exception as e:
                print("  ", tag, "FAILED:", e); continue
            for stage in (mx_gen.VERTEX_STAGE, mx_gen.PIXEL_STAGE):
                ext = {"glsl": "glsl", "slang": "slang"}[tag.split("_")[0]]
                p = os.path.join(HERE, "out", f"{m}_{tag}_{stage}.{ext}")
                open(p, "w").write(sh.getSourceCode(stage))
            print("  ", tag, "ok", len(sh.getSourceCode(mx_gen.PIXEL_STAGE)), "chars pixel")
