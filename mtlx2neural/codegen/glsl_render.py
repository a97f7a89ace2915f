"""Render MaterialX materials on a sphere with MaterialX's own GLSL renderer (``GlslRenderer``).

Used to check the neural material's MaterialX node (:mod:`.materialx_node`) in a renderer that
this project did not write. ``GlslRenderer`` needs an OpenGL context: offscreen, that is Xvfb with
Mesa's llvmpipe (Debian: ``xvfb``, ``libgl1-mesa-dri``, ``libglx-mesa0``). Its ``initialize()``
ends the whole process (exit status 1) when there is no display, so rendering always runs in a
child process: :func:`render_plan` runs ``xvfb-run -a python -m mtlx2neural.codegen.glsl_render
PLAN.json`` and returns its results; :func:`gl_unavailable` says why that cannot work here.

A plan (JSON) holds::

    {"geometry": "sphere.obj" (optional: a UV sphere written by write_sphere_obj),
     "lights": "rig.mtlx" (optional: a document of light nodes, e.g. directional_light),
     "environment": "radiance.exr", "irradiance": "irradiance.exr" (optional lat-long maps; none = black),
     "environment_method": "fis" | "prefilter", "environment_samples": 16,
     "camera": {"distance": 3.0, "fov": 45.0},
     "renders": [{"mtlx": "...", "material": "M" (optional), "out": "x.exr", "size": 256, "frames": 3}]}

(``frames``: timed draws after the first; 0 draws once and times nothing. A render may set its own
``lights``, ``environment``, ``irradiance`` and ``environment_samples``; null switches one off.)

Every render writes a float RGBA OpenEXR (row 0 at the top, linear HDR: no display transform);
background pixels (the renderer's clear colour) get RGB 0 and alpha 0, covered pixels alpha 1.
Transparency as in MaterialX's viewers: a material that ``MaterialX.isTransparentSurface`` calls
transparent (a surface whose ``opacity`` is set or connected, transmission) is generated with the
``hwTransparency`` option, so its shader writes alpha = 1 - mean(transparency) and discards fragments
with alpha below 0.001, and GlslRenderer blends the rest (source alpha, one minus source alpha) over its
clear colour (MaterialX's default screen colour, sRGB (0.3, 0.3, 0.32) in linear Rec. 709, about (0.073,
0.073, 0.084); reported per render as ``background``), back faces included (no culling). A cut-out's empty
part (opacity 0) thus shows the background, or the inside of the geometry behind it, exactly; a blended
surface's pixels mix in the clear colour and the faces behind, and weight its own colour by the opacity
twice (the surface node has already multiplied it; measured: a white emitter at opacity 0.5 on the sphere
reads 0.393, two layers over the background).
The results (JSON on stdout) give per render the median seconds per frame (a draw plus the
read-back, after one warm-up draw that includes llvmpipe's shader compilation; None without timed
frames) and the first frame's.

Conventions match :mod:`mtlx2neural.render`: world y up; the camera at (0, 0, distance) looks at
the origin with a vertical field of view ``fov``; the sphere is the unit sphere with u = 0.5 +
atan2(x, z) / 2pi, v = acos(-y) / pi. MaterialX's environment matrix rotates the lat-long map by
180 degrees about y relative to :class:`mtlx2neural.render.lighting.EnvironmentMap` (a direction
d is looked up at (-d.x, d.y, -d.z)); :func:`environment_for_torch` converts a map. A
``directional_light``'s ``direction`` is the direction the light travels (from the light).
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mtlx2neural.codegen.materialx_node import generation_context, load_node_document
from mtlx2neural.errors import Mtlx2NeuralError
from mtlx2neural.graph.library import standard_library
from mtlx2neural.render.prefiltered import IRRADIANCE_SIZE, irradiance_image

TIMEOUT = 300.0
LIGHTING_KEYS = ("lights", "environment", "irradiance", "environment_samples")
"""Plan keys that a render may also set for itself."""


def gl_unavailable() -> str | None:
    """Why MaterialX's GLSL renderer cannot run here (None when it can): it needs ``xvfb-run``
    or a DISPLAY, and the MaterialX wheel's render modules."""
    try:
        import MaterialX.PyMaterialXRenderGlsl  # noqa: F401  (Local: only probing that it imports)
    except ImportError as exc:
        return f"MaterialX's GLSL renderer module cannot be imported ({exc})"
    if shutil.which("xvfb-run") is None and not os.environ.get("DISPLAY"):
        return "no X display and no xvfb-run (install xvfb, libgl1-mesa-dri, libglx-mesa0)"
    return None


def write_sphere_obj(path, segments: int = 128, rings: int = 64) -> Path:
    """A unit UV sphere as a Wavefront OBJ: u = 0.5 + atan2(x, z) / 2pi, v = acos(-y) / pi,
    vertex normals = positions; ``segments`` around y, ``rings`` from pole to pole."""
    lines = ["# unit UV sphere (mtlx2neural.codegen.glsl_render)"]
    for i in range(rings + 1):
        v = i / rings
        theta = math.pi * v  # from the south pole
        y, r = -math.cos(theta), math.sin(theta)
        for j in range(segments + 1):
            u = j / segments
            phi = 2 * math.pi * (u - 0.5)
            x, z = r * math.sin(phi), r * math.cos(phi)
            lines += [f"v {x:.7f} {y:.7f} {z:.7f}", f"vn {x:.7f} {y:.7f} {z:.7f}", f"vt {u:.7f} {v:.7f}"]
    for i in range(rings):
        for j in range(segments):
            a = i * (segments + 1) + j + 1
            b, c, d = a + 1, a + segments + 2, a + segments + 1
            lines.append(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c} {d}/{d}/{d}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def directional_light_rig(direction, intensity: float = 3.0, color=(1.0, 1.0, 1.0)) -> str:
    """A MaterialX light rig with one ``directional_light``; ``direction`` is where the light
    points *to* (MaterialX's convention: the opposite of the direction towards the light)."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    return ('<?xml version="1.0"?>\n<materialx version="1.39">\n'
            '  <directional_light name="key" type="lightshader">\n'
            f'    <input name="direction" type="vector3" value="{d[0]:.7g}, {d[1]:.7g}, {d[2]:.7g}" />\n'
            f'    <input name="color" type="color3" value="{color[0]:.7g}, {color[1]:.7g}, {color[2]:.7g}" />\n'
            f'    <input name="intensity" type="float" value="{float(intensity):.7g}" />\n'
            "  </directional_light>\n</materialx>\n")


def environment_for_torch(image: np.ndarray) -> np.ndarray:
    """The lat-long map ``image`` [H, W, C] as :class:`~mtlx2neural.render.lighting.EnvironmentMap`
    must hold it to light the scene as MaterialX's renderer lights it with ``image``: rolled by half
    its width (MaterialX's default environment matrix turns the map 180 degrees about y)."""
    return np.roll(image, image.shape[1] // 2, axis=1)


def irradiance_map(radiance: np.ndarray, height: int = IRRADIANCE_SIZE[0], width: int = IRRADIANCE_SIZE[1]) -> np.ndarray:
    """The cosine-convolved irradiance divided by pi of a lat-long ``radiance`` map [H, W, 3]
    (what MaterialX's FIS mode reads from its irradiance map for diffuse lobes), [height, width, 3]
    float32, by direct quadrature (:func:`~mtlx2neural.render.prefiltered.irradiance_image`: the torch
    twin reads the same image; MaterialX's lat-long directions are the torch renderer's)."""
    return irradiance_image(radiance, height, width).numpy().astype(np.float32)


def write_exr(path, image: np.ndarray) -> None:
    """Write a float32 [H, W, C] array (row 0 at the top) as OpenEXR with OpenImageIO."""
    import OpenImageIO as oiio  # Local: OpenImageIO only where images are written

    img = np.ascontiguousarray(image, np.float32)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "float")):
        raise OSError(f"{path}: cannot write ({oiio.geterror()})")
    out.write_image(img)
    out.close()


def read_exr(path) -> np.ndarray:
    """A float32 [H, W, C] array (row 0 at the top) from an image file."""
    import OpenImageIO as oiio  # Local: OpenImageIO only where images are read

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        px = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if px is None:
            raise OSError(f"{path}: cannot decode ({inp.geterror()})")
        return np.asarray(px, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    finally:
        inp.close()


def render_plan(plan: dict, workdir=None, timeout: float = TIMEOUT) -> dict:
    """Run ``plan`` (module docstring) in a child process under ``xvfb-run -a`` (or on the current
    DISPLAY without it); returns its results ``{"renders": [{"out", "seconds_per_frame", "first_frame",
    "background", "covered", "transparent"}], "renderer": GL_RENDERER}``. Raises Mtlx2NeuralError with
    the child's output when it fails."""
    reason = gl_unavailable()
    if reason:
        raise Mtlx2NeuralError(f"MaterialX's GLSL renderer cannot run: {reason}")
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        plan_path = Path(tmp) / "plan.json"
        plan_path.write_text(json.dumps(plan, indent=1))
        cmd = [sys.executable, "-m", "mtlx2neural.codegen.glsl_render", str(plan_path)]
        if shutil.which("xvfb-run"):
            cmd = ["xvfb-run", "-a", "-s", "-screen 0 1024x768x24"] + cmd
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise Mtlx2NeuralError(f"MaterialX's GLSL renderer took longer than {timeout:.0f} s") from None
    marker = "GLSL_RENDER_RESULTS "
    found = [line for line in proc.stdout.splitlines() if line.startswith(marker)]
    if proc.returncode != 0 or not found:
        raise Mtlx2NeuralError(f"MaterialX's GLSL renderer failed (exit status {proc.returncode}):\n"
                               f"{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}")
    return json.loads(found[-1][len(marker):])


# ------------------------------------------------------------------------------ the child process


def _oiio_loader_class():
    """A MaterialX ImageLoader backed by OpenImageIO (the wheel's stb loader cannot read EXR):
    level 0 of the file, float32, rows as stored (row 0 at the top)."""
    import MaterialX.PyMaterialXRender as mx_render  # Local: the render modules load GL only in the child

    class OiioLoader(mx_render.ImageLoader):
        def __init__(self):
            super().__init__()
            self.loaded, self.failed = [], []

        def supportedExtensions(self):
            return {"exr", "hdr", "tif", "tiff", "png"}

        def loadImage(self, file_path):
            try:
                data = read_exr(file_path.asString())
            except OSError as exc:
                self.failed.append(str(exc))
                return None
            self.loaded.append(file_path.asString())
            h, w, c = data.shape
            c = min(c, 4)
            data = np.ascontiguousarray(data[..., :c])
            img = mx_render.Image.create(w, h, c, mx_render.BaseType.FLOAT)
            img.createResourceBuffer()
            ctypes.memmove(img.getResourceBuffer(), data.ctypes.data, data.nbytes)
            return img

    return OiioLoader


def _to_numpy(img) -> np.ndarray:
    import MaterialX.PyMaterialXRender as mx_render  # Local: see _oiio_loader_class

    w, h, c = img.getWidth(), img.getHeight(), img.getChannelCount()
    assert img.getBaseType() == mx_render.BaseType.FLOAT
    buf = (ctypes.c_char * (w * h * c * 4)).from_address(img.getResourceBuffer())
    return np.frombuffer(buf, np.float32).reshape(h, w, c)[::-1].copy()  # GL rows start at the bottom


def _check_files(doc, mtlx: Path) -> None:
    """Raise naming the first file a node of ``doc`` reads that does not exist: MaterialX's image
    handler would print a warning and render with a fallback colour."""
    for node in doc.getNodes():
        for inp in node.getInputs():
            value = inp.getValueString() if inp.getType() == "filename" else ""
            if value and not (mtlx.resolve().parent / value).is_file():
                raise Mtlx2NeuralError(f"{mtlx}: node {node.getName()} reads {value}, which does not exist "
                                       f"(relative paths are taken from the document's folder)")


def _gl_renderer() -> str | None:
    """The current GL context's ``GL_RENDERER`` and ``GL_VERSION`` strings (e.g. "llvmpipe (LLVM
    15.0.6, 256 bits); 4.5 (Compatibility Profile) Mesa 22.3.6"), None where libGL cannot be asked."""
    try:
        gl = ctypes.CDLL("libGL.so.1")
        gl.glGetString.restype = ctypes.c_char_p
        gl.glGetString.argtypes = [ctypes.c_uint]
        names = [gl.glGetString(code) for code in (0x1F01, 0x1F02)]  # GL_RENDERER, GL_VERSION
    except (OSError, AttributeError):
        return None
    return "; ".join(n.decode() for n in names if n) or None


def _run(plan: dict) -> dict:
    # Local: MaterialX's render modules and the generator helpers run only in the child process.
    import MaterialX as mx
    import MaterialX.PyMaterialXGenGlsl as mx_glsl
    import MaterialX.PyMaterialXGenShader as mx_gen
    import MaterialX.PyMaterialXRender as mx_render
    import MaterialX.PyMaterialXRenderGlsl as mx_rglsl

    renders = plan["renders"]
    renderer = mx_rglsl.GlslRenderer.create(renders[0]["size"], renders[0]["size"], mx_render.BaseType.FLOAT)
    renderer.initialize()  # exits the process without a display: hence the child process
    gl_name = _gl_renderer()
    images = mx_rglsl.GLTextureHandler.create(mx_render.StbImageLoader.create())
    loader = _oiio_loader_class()()  # kept referenced: MaterialX holds only the C++ half of it
    images.addLoader(loader)
    renderer.setImageHandler(images)

    lights = mx_render.LightHandler.create()
    zero = images.getZeroImage()
    rigs = {}

    def light(job: dict):
        """Set up ``lights`` for ``job`` (its own lighting keys, else the plan's); returns the rig
        document and its light nodes (None, [] without a rig)."""
        cfg = {k: job.get(k, plan.get(k)) for k in LIGHTING_KEYS}
        rig, nodes = None, []
        if cfg["lights"]:
            if cfg["lights"] not in rigs:
                rig = mx.createDocument()
                mx.readFromXmlFile(rig, cfg["lights"])
                rig.setDataLibrary(standard_library())
                rigs[cfg["lights"]] = (rig, [n for n in rig.getNodes() if n.getType() == "lightshader"])
            rig, nodes = rigs[cfg["lights"]]
        for key, setter in (("environment", lights.setEnvRadianceMap), ("irradiance", lights.setEnvIrradianceMap)):
            setter(images.acquireImage(mx.FilePath(cfg[key])) if cfg[key] else zero)
        lights.setEnvSampleCount(int(cfg["environment_samples"] or 16))
        lights.setLightSources(nodes)
        return rig, nodes

    renderer.setLightHandler(lights)

    geometry = renderer.getGeometryHandler()
    geometry.addLoader(mx_render.TinyObjLoader.create())
    with tempfile.TemporaryDirectory() as tmp:
        obj = plan.get("geometry") or str(write_sphere_obj(Path(tmp) / "sphere.obj"))
        if not geometry.loadGeometry(mx.FilePath(obj), False):
            raise Mtlx2NeuralError(f"{obj}: MaterialX cannot load the geometry")
    cam = plan.get("camera", {})
    distance, fov = float(cam.get("distance", 3.0)), float(cam.get("fov", 45.0))
    camera = renderer.getCamera()
    camera.setViewMatrix(mx_render.Camera.createViewMatrix(mx.Vector3(0, 0, distance), mx.Vector3(0, 0, 0),
                                                           mx.Vector3(0, 1, 0)))
    near = 0.05
    half = near * math.tan(math.radians(fov) / 2)
    camera.setProjectionMatrix(mx_render.Camera.createPerspectiveMatrix(-half, half, -half, half, near, 100.0))

    generator = mx_glsl.GlslShaderGenerator.create()
    # Colour management as MaterialX's viewers set it up: without it an image input's colour space
    # (e.g. srgb_texture on a PNG albedo) is ignored and the texture is read as linear.
    cms = mx_gen.DefaultColorManagementSystem.create(generator.getTarget())
    cms.loadLibrary(standard_library())
    generator.setColorManagementSystem(cms)
    results = []
    for job in renders:
        doc = load_node_document(job["mtlx"])
        _check_files(doc, Path(job["mtlx"]))
        # The handler caches images by the name a document gives them: two documents naming
        # different latents_0.exr files relative to their folders would share one without this.
        images.clearImageCache()
        images.setSearchPath(mx.FileSearchPath(str(Path(job["mtlx"]).resolve().parent)))
        ctx = generation_context(generator, job["mtlx"], environment=plan.get("environment_method", "fis"))
        rig, nodes = light(job)
        if rig is not None:
            lights.registerLights(rig, nodes, ctx)  # before generate: binds the light functions
        material = doc.getNode(job["material"]) if job.get("material") else doc.getMaterialNodes()[0]
        # As MaterialX's viewers: a surface with an opacity (or transmission) is generated transparent, so
        # the shader writes alpha and discards what is fully transparent, and the renderer blends the rest.
        transparent = bool(mx_gen.isTransparentSurface(material, generator.getTarget()))
        ctx.getOptions().hwTransparency = transparent
        shader = generator.generate(material.getName(), material, ctx)
        size = int(job["size"])
        renderer.setSize(size, size)
        renderer.createProgram(shader)
        renderer.validateInputs()
        start = time.perf_counter()
        renderer.render()
        img = renderer.captureImage(None)
        first = time.perf_counter() - start
        times = []
        for _ in range(max(int(job.get("frames", 3)), 0)):
            start = time.perf_counter()
            renderer.render()
            img = renderer.captureImage(None)
            times.append(time.perf_counter() - start)
        if loader.failed:
            raise Mtlx2NeuralError("MaterialX's renderer could not load: " + "; ".join(loader.failed))
        rgba = _to_numpy(img)
        background = rgba[0, 0, :3].copy()
        covered = ~np.all(rgba[..., :3] == background, -1)
        out = np.concatenate([np.where(covered[..., None], rgba[..., :3], 0.0), covered[..., None]], -1)
        write_exr(job["out"], out)
        results.append({"out": job["out"], "material": material.getName(), "size": size,
                        "seconds_per_frame": float(np.median(times)) if times else None, "first_frame": first,
                        "background": background.tolist(), "covered": int(covered.sum()),
                        "transparent": transparent})
    return {"renders": results, "images_loaded": sorted(set(loader.loaded)), "renderer": gl_name}


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: xvfb-run -a python -m mtlx2neural.codegen.glsl_render PLAN.json", file=sys.stderr)
        return 2
    results = _run(json.loads(Path(args[0]).read_text()))
    print("GLSL_RENDER_RESULTS " + json.dumps(results), flush=True)
    sys.stderr.flush()
    # MaterialX's GL objects can crash on interpreter shutdown (seen: a double free); the results
    # are written, so leave without running destructors.
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
