"""Offscreen render of a MaterialX material on a sphere with GlslRenderer (run under xvfb-run).

usage: xvfb-run -a -s "-screen 0 1024x768x24" python render.py MATERIAL.mtlx MATERIAL_NAME out.png
       [--size 256] [--env-mode 0|1] [--env-samples N] [--explicit-mix F] [--lod F] [--prefilter]
"""
import argparse, ctypes, os, sys, time
import numpy as np
import MaterialX as mx
import MaterialX.PyMaterialXGenShader as mx_gen
import MaterialX.PyMaterialXGenGlsl as mx_glsl
import MaterialX.PyMaterialXRender as mx_render
import MaterialX.PyMaterialXRenderGlsl as mx_rglsl
import OpenImageIO as oiio
from gen import load_doc, make_context, HERE

RES = os.environ.get("MX_RESOURCES", "/work/shared/assets/materialx/resources")

class OiioLoader(mx_render.ImageLoader):
    """Minimal EXR/HDR loader (the wheel's StbImageLoader cannot read EXR)."""
    def __init__(self):
        super().__init__()
    def supportedExtensions(self):
        return {"exr", "hdr"}
    def loadImage(self, filePath):
        inp = oiio.ImageInput.open(filePath.asString())
        if not inp:
            return None
        spec = inp.spec(); ch = min(spec.nchannels, 4)
        data = np.ascontiguousarray(inp.read_image(0, 0, 0, ch, oiio.FLOAT), np.float32)
        inp.close()
        img = mx_render.Image.create(spec.width, spec.height, ch, mx_render.BaseType.FLOAT)
        img.createResourceBuffer()
        ctypes.memmove(img.getResourceBuffer(), data.ctypes.data, data.nbytes)
        return img

def image_to_numpy(img):
    w, h, c = img.getWidth(), img.getHeight(), img.getChannelCount()
    n = w * h * c * img.getBaseStride()
    buf = (ctypes.c_char * n).from_address(img.getResourceBuffer())
    dt = {mx_render.BaseType.UINT8: np.uint8, mx_render.BaseType.FLOAT: np.float32}[img.getBaseType()]
    return np.frombuffer(buf, dtype=dt).reshape(h, w, c).copy()

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mtlx"); ap.add_argument("material"); ap.add_argument("png")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--env-mode", type=int); ap.add_argument("--env-samples", type=int)
    ap.add_argument("--explicit-mix", type=float); ap.add_argument("--lod", type=float)
    ap.add_argument("--prefilter", action="store_true")
    ap.add_argument("--no-direct", action="store_true")
    ap.add_argument("--float", action="store_true", help="FLOAT framebuffer (unclamped), saves .npy only")
    ap.add_argument("--latent-file", help="override the image node's latent EXR")
    a = ap.parse_args()
    t0 = time.time()

    doc, stdlib, ok, msg = load_doc(a.mtlx)
    assert ok, msg
    # optional per-run overrides of the custom node inputs
    for node in doc.getNodes():
        if node.getCategory() != "myneural_bsdf":
            continue
        for name, val in [("env_mode", a.env_mode), ("env_samples", a.env_samples),
                          ("explicit_mix", a.explicit_mix), ("latent_lod", a.lod)]:
            if val is not None:
                node.setInputValue(name, val)
    if a.latent_file:
        doc.getNode("latent_img").setInputValue("file", a.latent_file, "filename")

    gen = mx_glsl.GlslShaderGenerator.create()
    ctx = make_context(gen, mx_gen.SPECULAR_ENVIRONMENT_PREFILTER if a.prefilter else mx_gen.SPECULAR_ENVIRONMENT_FIS)

    # --- renderer + handlers -------------------------------------------------
    W = H = a.size
    renderer = mx_rglsl.GlslRenderer.create(W, H, mx_render.BaseType.FLOAT if a.float else mx_render.BaseType.UINT8)
    renderer.initialize()                     # needs a GL context -> X display (Xvfb)
    img_handler = mx_rglsl.GLTextureHandler.create(mx_render.StbImageLoader.create())
    loader = OiioLoader(); img_handler.addLoader(loader)
    sp = mx.FileSearchPath(HERE); sp.append(mx.FilePath(RES))
    img_handler.setSearchPath(sp)
    renderer.setImageHandler(img_handler)

    light_handler = mx_render.LightHandler.create()
    light_doc = mx.createDocument()
    mx.readFromXmlFile(light_doc, os.path.join(RES, "Lights/san_giuseppe_bridge_split.mtlx"))
    light_doc.setDataLibrary(stdlib)
    lights = [] if a.no_direct else [n for n in light_doc.getNodes() if n.getType() == "lightshader"]
    light_handler.registerLights(light_doc, lights, ctx)   # binds light impls into ctx (before generate)
    light_handler.setLightSources(lights)
    light_handler.setEnvRadianceMap(img_handler.acquireImage(mx.FilePath(os.path.join(HERE, "env_radiance.hdr"))))
    light_handler.setEnvIrradianceMap(img_handler.acquireImage(mx.FilePath(os.path.join(HERE, "env_irradiance.hdr"))))
    light_handler.setEnvSampleCount(64)
    renderer.setLightHandler(light_handler)

    geo = renderer.getGeometryHandler()
    geo.addLoader(mx_render.TinyObjLoader.create())
    assert geo.loadGeometry(mx.FilePath(os.path.join(RES, "Geometry/sphere.obj")), False)

    cam = renderer.getCamera()
    cam.setViewMatrix(mx_render.Camera.createViewMatrix(mx.Vector3(0, 0, 3.2), mx.Vector3(0, 0, 0), mx.Vector3(0, 1, 0)))
    f = 0.05 * np.tan(np.radians(45) / 2)
    cam.setProjectionMatrix(mx_render.Camera.createPerspectiveMatrix(-f, f, -f, f, 0.05, 100.0))

    # --- generate + render --------------------------------------------------
    t1 = time.time()
    shader = gen.generate(a.material, doc.getNode(a.material), ctx)
    t2 = time.time()
    renderer.createProgram(shader)
    renderer.validateInputs()
    t3 = time.time()
    renderer.render()                         # first draw also JIT-compiles on llvmpipe
    img = renderer.captureImage(None)
    t4 = time.time()
    renderer.render(); renderer.captureImage(None)
    t5 = time.time()
    if not a.float:
        img_handler.saveImage(mx.FilePath(a.png), img, True)
    arr = image_to_numpy(img)
    np.save(os.path.splitext(a.png)[0] + ".npy", arr)
    print(f"timing: setup {t1-t0:.2f}s  generate {t2-t1:.2f}s  compile/link {t3-t2:.2f}s  "
          f"1st render+readback {t4-t3:.2f}s  2nd render+readback {t5-t4:.2f}s  total {time.time()-t0:.2f}s")
    print("mean rgb:", arr[..., :3].reshape(-1, 3).mean(0))

if __name__ == "__main__":
    main()
