"""A neural material as a MaterialX node: a BSDF nodedef with ``genglsl`` and ``genslang``
implementations, and a ``surface`` + ``surfacematerial`` over an instance of it.

:func:`write_materialx_node` writes, for one material, into one folder::

    NeuralMaterial_<ident>.mtlx    the document (below), written last
    NeuralMaterial_<ident>.glsl    its genglsl implementation   (:func:`.materialx_shader.node_source`)
    NeuralMaterial_<ident>.slang   its genslang implementation

each atomically (a temporary sibling renamed into place). The document holds

- the nodedef ``ND_neural_<ident>_bsdf`` (node ``neural_<ident>_bsdf``, type ``BSDF``,
  ``bsdf="R"``: reflection only, so the surface node never calls it for transmission) with the
  inputs ``weight`` (float, 1), ``latent0`` .. ``latent<G-1>`` (filename: the latent textures,
  four channels each), ``texcoord`` (vector2, default geometry property UV0), ``normal``
  (vector3, Nworld), ``tangent`` (vector3, Tworld) and ``env_samples`` (uniform integer: learned
  sampler directions per pixel for environment light, or with ``env_prefiltered`` lookups per
  specular lobe; 0 or less uses the viewer's FIS sample count) and ``env_prefiltered`` (uniform
  boolean, default true for a material with an environment head, else false: shade the environment
  from the learned lobes' prefiltered lookups, no random numbers; :mod:`mtlx2neural.render.prefiltered`
  is its torch twin);
- the implementations ``IM_neural_<ident>_bsdf_genglsl`` / ``_genslang`` (``file`` relative to
  the document, function ``mx_neural_<ident>_bsdf``);
- ``N_neural_<ident>`` (the node, its latent inputs set to the texture files, relative to the
  document), ``SR_neural_<ident>`` (a ``surface``) and ``M_neural_<ident>`` (a ``surfacematerial``);
- for a material that emits or is not opaque (the export's ``surface.json``), standard nodes feeding the
  surface's ``edf`` and ``opacity`` (:func:`add_surface_nodes`): ``N_neural_<ident>_edf`` (a
  ``uniform_edf`` whose colour is the constant emission or ``N_neural_<ident>_emission``, an ``image``
  node reading ``emission.exr``), and the opacity as a constant or ``N_neural_<ident>_opacity`` (an
  ``image`` reading ``opacity.exr``), for a cut-out through ``N_neural_<ident>_cutout`` (an
  ``ifgreatereq`` at 0.5, as UsdPreviewSurface's graph tests ``opacityThreshold``).

The emission and opacity maps are the export's files, copied whole (MIP chain included) beside the
document. MaterialX's viewers read level 0 and build their own MIP maps (GLTextureHandler does), as they
would from a level-0 file; a host whose texture system reads a file's own MIP levels (OpenImageIO's
TextureSystem does) gets the exported ones (coverage-weighted emission, coverage-preserving cut-outs). An atlas read by a custom node, as for the
latents, would keep the levels everywhere but work only in the genglsl / genslang implementations; these
are stdlib and pbrlib nodes, which every MaterialX back end and hdMtlx understands. The cost: in a viewer
that builds its own MIP maps, a cut-out's thin parts thin out with distance and its emission mixes in the
empty texels' values at its edges.

The latent textures are the export's OpenEXR MIP chains (``latents_<k>.exr``, RGBA, level 0 the
finest, row 0 the top). They are checked when the node is written: a missing, unreadable or
malformed file, or one that does not fit the networks, raises :class:`~mtlx2neural.errors.InputError`
naming it. The node does not read them directly: viewers build their own MIP maps from level 0
(MaterialX's GLTextureHandler does), which would replace the learned coarse levels with box-filtered
ones. So each chain is also written, beside the document, as one single-level atlas
(``latent_atlas_<k>.exr``: every level a rectangle, :func:`.materialx_shader.atlas_layout`), and the
node's latent inputs name the atlases; the shader reads each level's rectangle itself. Every level
is then exact in any viewer.

A UDIM material (tiles in the manifest's ``udim_tiles``) reads ``latents_<k>.<UDIM>.exr`` per tile;
each atlas then holds the tiles' pyramids side by side (tile k's block k pyramid widths from the
left), and the shader picks the block from floor(uv) (its tile table; a tile it was not trained on
shades black, as the Slang module), reads frac(uv) in it and clamps at the tile's edges. MaterialX's
own UDIM handling (an image node over a host-built atlas normalised to the set's bounding box) is
not involved: the node addresses its atlas itself.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import MaterialX as mx
import MaterialX.PyMaterialXGenGlsl as mx_glsl
import MaterialX.PyMaterialXGenShader as mx_gen
import MaterialX.PyMaterialXGenSlang as mx_slang
import numpy as np
import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.codegen.generate import _describe_source, _version
from mtlx2neural.codegen.materialx_shader import (
    LatentLayout,
    atlas_layout,
    function_name,
    node_source,
    prefix,
)
from mtlx2neural.codegen.spec import (
    SurfaceSpec,
    as_spec,
    read_surface_spec,
    surface_spec,
)
from mtlx2neural.errors import InputError, Mtlx2NeuralError
from mtlx2neural.formats.latent_codec import (
    block_texture_names,
    codec_of,
    read_block_textures,
)
from mtlx2neural.graph.library import standard_library, with_libraries
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.textures.surface_maps import MANIFEST_FILE

DEFAULT_ENV_SAMPLES = 16
"""Learned-sampler directions per pixel for environment light (MaterialXView's FIS default count)."""


@dataclass(frozen=True)
class NodeNames:
    """The names of one material's MaterialX elements and files (see the module docstring)."""

    ident: str
    nodedef: str
    category: str
    node: str
    surface: str
    material: str
    function: str
    mtlx: str
    glsl: str
    slang: str
    edf: str = ""
    emission: str = ""
    opacity: str = ""
    cutout: str = ""


def node_names(name: str) -> NodeNames:
    """The element and file names of material ``name`` (any string; '/World/Looks/Car Paint' -> Car_Paint)."""
    ident = prefix(name)
    stem = f"NeuralMaterial_{ident}"
    node = f"N_neural_{ident}"
    return NodeNames(ident, f"ND_neural_{ident}_bsdf", f"neural_{ident}_bsdf", node,
                     f"SR_neural_{ident}", f"M_neural_{ident}", function_name(name), f"{stem}.mtlx", f"{stem}.glsl",
                     f"{stem}.slang", f"{node}_edf", f"{node}_emission", f"{node}_opacity", f"{node}_cutout")


def latent_file_names(channels: int) -> list[str]:
    """The export's latent texture names for ``channels`` channels (``latents_0.exr``, ... : four
    channels each; the naming of :func:`mtlx2neural.export.latents.texture_names`)."""
    return [f"latents_{k}.exr" for k in range(math.ceil(channels / 4))]


def atlas_file_names(groups: int) -> list[str]:
    """The node's latent atlas names for ``groups`` RGBA groups (``latent_atlas_0.exr``, ...)."""
    return [f"latent_atlas_{k}.exr" for k in range(groups)]


# ------------------------------------------------------------------------------ latent textures


def _latent_chain(path: Path) -> list[np.ndarray]:
    """Every MIP level of the latent texture at ``path`` ([H_j, W_j, 4] float16, finest first), each
    decoded and checked (:func:`mtlx2neural.imaging.mip_chain.read_mip_chain`); raises InputError
    naming the file."""
    chain = read_mip_chain(path)
    for j, level in enumerate(chain):
        if not np.isfinite(level).all():
            raise InputError(f"latent texture {path}: MIP level {j} holds non-finite values")
    return chain


def latent_atlas(chain: list[np.ndarray]) -> np.ndarray:
    """One [H, W, 4] float16 image holding every level of ``chain`` at its
    :func:`.materialx_shader.atlas_layout` rectangle (rows from the top; unused texels 0). A list of
    chains (a UDIM material's tiles, in slot order, all of one layout) gives their atlases side by
    side, tile k's block k atlas widths from the left."""
    if chain and isinstance(chain[0], (list, tuple)):
        return np.concatenate([latent_atlas(c) for c in chain], axis=1)
    rects, (height, width) = atlas_layout([level.shape[:2] for level in chain])
    atlas = np.zeros((height, width, 4), np.float16)
    for (x, y, w, h), level in zip(rects, chain):
        atlas[y:y + h, x:x + w] = level
    return atlas


def _tile_file(path, tile: int) -> Path:
    """The file of UDIM ``tile`` for ``path``: its ``<UDIM>`` token replaced, else ``latents_<k>.exr`` ->
    ``latents_<k>.<tile>.exr`` (the export's names)."""
    path = Path(path)
    if "<UDIM>" in path.name:
        return path.with_name(path.name.replace("<UDIM>", str(tile)))
    return path.with_name(f"{path.stem}.{tile}{path.suffix}")


def write_latent_atlas(chain: list[np.ndarray], path: Path) -> Path:
    """Write :func:`latent_atlas` of ``chain`` as a half-float RGBA OpenEXR at ``path`` (atomically;
    one level, no MIP maps: the viewer's own would mix the levels' rectangles)."""
    import OpenImageIO as oiio  # Local: OpenImageIO only where the atlases are written

    atlas = latent_atlas(chain)
    spec = oiio.ImageSpec(atlas.shape[1], atlas.shape[0], 4, "half")
    spec.attribute("compression", "zip")
    spec.attribute("oiio:ColorSpace", "raw")
    nested = bool(chain) and isinstance(chain[0], (list, tuple))
    first = chain[0] if nested else chain
    spec.attribute("mtlx2neural:atlasLevels", json.dumps(atlas_layout([lv.shape[:2] for lv in first])[0]))
    if nested and len(chain) > 1:  # UDIM: one block per tile, this many side by side
        spec.attribute("mtlx2neural:atlasTiles", len(chain))
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(path))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{path}: OpenImageIO cannot write OpenEXR ({oiio.geterror()})")
        ok = out.write_image(np.ascontiguousarray(atlas))
        if not out.close() or not ok:
            raise OSError(f"{path}: cannot write the latent atlas ({out.geterror()})")
    return path


def _block_chains(paths, codec) -> list[list[np.ndarray]]:
    """Block-compressed latent textures (DDS, three channels each) decoded and regrouped into the
    node's RGBA groups: channels 4g .. 4g + 3 per chain ([H_j, W_j, 4] float16, finest first; a BC6H
    texel is a half, so exactly; a BC1 texel after its scale and offset, rounded to half)."""
    levels = read_block_textures(paths, codec)
    c = codec.channels
    chains = []
    for g in range(math.ceil(c / 4)):
        chain = []
        for lv in levels:
            part = lv[4 * g: 4 * g + 4]
            part = torch.cat([part, part.new_zeros(4 - part.shape[0], *part.shape[1:])])
            chain.append(part.permute(1, 2, 0).numpy().astype(np.float16))
        chains.append(chain)
    return chains


def read_latent_files(paths, channels: int, resolution: tuple[int, int] | None = None,
                      levels: int | None = None, codec=None) -> tuple[LatentLayout, list[list[np.ndarray]]]:
    """Read and check the latent textures ``paths`` (in channel order) for ``channels`` latent
    channels; returns (their layout, each RGBA group's MIP chain as :func:`_latent_chain` reads it).
    ``resolution`` (height, width of level 0) and ``levels``, when given, are what the networks were
    trained with; ``codec`` (:class:`~mtlx2neural.formats.latent_codec.LatentCodec`): the paths are its
    DDS textures, decoded here. Raises InputError naming the offending file."""
    paths = [Path(p) for p in paths]
    groups = math.ceil(channels / 4)
    if codec is not None:
        images = _block_chains(paths, codec)
        paths = [paths[0]] * groups  # the chains are regrouped: name the first file in errors
    elif len(paths) != groups:
        raise InputError(f"{channels} latent channels are stored in {groups} latent texture(s), got {len(paths)}: "
                         f"{', '.join(map(str, paths)) or 'none'}")
    else:
        images = [_latent_chain(p) for p in paths]
    chains = [[tuple(level.shape[:2]) for level in chain] for chain in images]
    for p, chain in zip(paths, chains):
        if resolution is not None and chain[0] != tuple(resolution):
            raise InputError(f"latent texture {p} is {chain[0][1]} x {chain[0][0]} texels; the networks were "
                             f"trained on a {resolution[1]} x {resolution[0]} latent grid")
        if levels is not None and len(chain) != levels:
            raise InputError(f"latent texture {p} has {len(chain)} MIP level(s); the latent pyramid has {levels}")
        if chain != chains[0]:
            raise InputError(f"latent texture {p}: MIP levels {chain} differ from {paths[0]}'s {chains[0]}")
    (h, w) = chains[0][0]
    return LatentLayout(channels, groups, w, h, len(chains[0]), tuple(chains[0])), images


def _expected_latents(model_or_export) -> tuple[tuple[int, int] | None, int | None]:
    """(level-0 (height, width), level count) the networks were trained with, where known."""
    if isinstance(model_or_export, (str, Path)):
        p = Path(model_or_export)
        manifest = p / "weights.json" if p.is_dir() else p
        try:
            arch = json.loads(manifest.read_text()).get("architecture", {})
        except (OSError, ValueError):
            return None, None  # as_spec reports an unreadable manifest
        res = arch.get("latent_resolution")  # [width, height]
        return (tuple(reversed(res)) if res else None), arch.get("levels")
    latents = getattr(model_or_export, "latents", None)
    if latents is not None and hasattr(latents, "levels"):
        return tuple(latents.levels[0].shape[-2:]), int(latents.num_levels)  # per tile for UDIM
    return None, None


def _udim_tiles(model_or_export) -> list[int] | None:
    """The UDIM tiles of a model (``latents.tile_list``) or export (manifest ``udim_tiles``), else None."""
    if isinstance(model_or_export, (str, Path)):
        p = Path(model_or_export)
        try:
            return json.loads((p / "weights.json" if p.is_dir() else p).read_text())["architecture"].get("udim_tiles")
        except (OSError, ValueError, KeyError, TypeError):
            return None  # as_spec reports an unreadable manifest
    return getattr(getattr(model_or_export, "latents", None), "tile_list", None)


# ------------------------------------------------------------------------------ the document


def build_document(name: str, layout: LatentLayout, latent_values: list[str],
                   env_samples: int = DEFAULT_ENV_SAMPLES, doc_string: str = "", surface: SurfaceSpec | None = None,
                   env_prefiltered: bool = False):
    """The MaterialX document of material ``name`` (module docstring); ``latent_values`` are the
    latent inputs' file names as the document will state them; ``surface``: the emission and opacity
    (its files named as the document states them), None: none and opaque; ``env_prefiltered`` the
    default of the node's input (True only for networks with an environment head)."""
    n = node_names(name)
    doc = mx.createDocument()
    nd = doc.addNodeDef(n.nodedef, "BSDF", n.category)
    nd.setNodeGroup("pbr")
    nd.setAttribute("bsdf", "R")
    nd.setDocString(doc_string or f"Neural BSDF of material {name} (mtlx2neural)")
    nd.addInput("weight", "float").setValue(1.0)
    for g in range(layout.groups):
        nd.addInput(f"latent{g}", "filename").setValueString("")
    nd.addInput("texcoord", "vector2").setDefaultGeomPropString("UV0")
    nd.addInput("normal", "vector3").setDefaultGeomPropString("Nworld")
    nd.addInput("tangent", "vector3").setDefaultGeomPropString("Tworld")
    samples = nd.addInput("env_samples", "integer")
    samples.setValue(int(env_samples))
    samples.setIsUniform(True)
    prefiltered = nd.addInput("env_prefiltered", "boolean")
    prefiltered.setValue(bool(env_prefiltered))
    prefiltered.setIsUniform(True)
    for target, file in (("genglsl", n.glsl), ("genslang", n.slang)):
        impl = doc.addImplementation(f"IM_neural_{n.ident}_bsdf_{target}")
        impl.setNodeDef(nd)
        impl.setTarget(target)
        impl.setFile(file)
        impl.setFunction(n.function)
    node = doc.addNode(n.category, n.node, "BSDF")
    for g, value in enumerate(latent_values):
        node.setInputValue(f"latent{g}", value, "filename")
    shader = doc.addNode("surface", n.surface, "surfaceshader")
    shader.setConnectedNode("bsdf", node)
    add_surface_nodes(doc, shader, n, surface)
    doc.addMaterialNode(n.material, shader)
    return doc


def add_surface_nodes(doc, shader, names: NodeNames, surface: SurfaceSpec | None) -> None:
    """Connect ``surface``'s emission and opacity to the ``surface`` node ``shader`` of ``doc``
    (module docstring): a ``uniform_edf`` on ``edf`` (its colour a constant or an ``image`` of the
    emission file, linear Rec. 709, periodic), and on ``opacity`` a constant (a cut-out's alpha-tested) or
    an ``image`` of the opacity file, through an ``ifgreatereq`` at 0.5 for a cut-out."""
    if surface is None:
        return

    def image(node_name: str, file: str, kind: str):
        img = doc.addNode("image", node_name, kind)
        f = img.addInput("file", "filename")
        f.setValueString(file)
        if kind == "color3":
            f.setColorSpace("lin_rec709")
        for axis in ("uaddressmode", "vaddressmode"):
            img.setInputValue(axis, "periodic", "string")
        return img

    if surface.emits:
        edf = doc.addNode("uniform_edf", names.edf, "EDF")
        if surface.emission_file is not None:
            edf.setConnectedNode("color", image(names.emission, surface.emission_file, "color3"))
        else:
            edf.setInputValue("color", mx.Color3(*surface.emission_constant), "color3")
        shader.setConnectedNode("edf", edf)
    if surface.opacity_file is not None:
        alpha = image(names.opacity, surface.opacity_file, "float")
        if surface.alpha_cutoff is not None:
            test = doc.addNode("ifgreatereq", names.cutout, "float")
            test.setConnectedNode("value1", alpha)
            test.setInputValue("value2", float(surface.alpha_cutoff), "float")
            test.setInputValue("in1", 1.0, "float")
            test.setInputValue("in2", 0.0, "float")
            alpha = test
        shader.setConnectedNode("opacity", alpha)
    elif surface.opacity_constant is not None:
        shader.setInputValue("opacity", float(surface.coverage_constant), "float")


def surface_files(model_or_export, base: Path, folder: Path) -> tuple[SurfaceSpec | None, list[tuple[Path, Path]]]:
    """The emission and opacity of the material whose export folder (or, for a model, the folder its
    latents are read from) is ``base``: its ``surface.json`` (:func:`.spec.read_surface_spec`; None when
    the material emits nothing and is opaque), each map checked (InputError naming it), and the copies
    to make: (file in ``base``, the same name in ``folder``), none for a file already there. Without a
    ``surface.json`` a model's own ``surface`` is used when it is constant; one with textured maps raises
    InputError (the files are needed)."""
    surface = read_surface_spec(base)
    if surface is None:
        own = surface_spec(model_or_export) if not isinstance(model_or_export, (str, Path)) else None
        if own is not None and own.textured:
            raise InputError(f"the model's emission or opacity is textured, but {base} holds no {MANIFEST_FILE}: "
                             f"write its maps there first (mtlx2neural.export.surface_files.write_surface_files)")
        return own, []
    copies = []
    for file, channels in ((surface.emission_file, 3), (surface.opacity_file, 1)):
        if file is None:
            continue
        src = base / file
        chain = read_mip_chain(src, channels, what="emission map" if channels == 3 else "opacity map")
        if surface.levels and len(chain) != surface.levels:
            raise InputError(f"{src} has {len(chain)} MIP level(s); {base / MANIFEST_FILE} says {surface.levels}")
        if (folder / file).resolve() != src.resolve():
            copies.append((src, folder / file))
    return surface, copies


def validate_document(doc, where: str = "the neural material document") -> None:
    """``doc.validate()`` with the standard libraries imported (on a copy); raises on failure."""
    ok, message = with_libraries(doc).validate()
    if not ok:
        raise Mtlx2NeuralError(f"{where} does not validate: {message.strip()}")


def write_materialx_node(model_or_export, name: str, folder, *, latent_files=None,
                         env_samples: int = DEFAULT_ENV_SAMPLES, seed: int = 0,
                         env_prefiltered: bool | None = None) -> Path:
    """Write ``NeuralMaterial_<ident>.mtlx`` and its ``.glsl`` / ``.slang`` implementations for
    material ``name`` into ``folder``; returns the ``.mtlx`` path.

    ``model_or_export``: a NeuralMaterial (float32 weights), an export folder or its
    ``weights.json`` (the FP16 weights as stored), or a NetworkSpec. ``latent_files``: the latent
    textures in channel order; by default ``latents_<k>.exr`` in the export folder, or in ``folder``
    for a model. They are checked (InputError naming the file when missing or malformed) and
    copied, level by level, into the atlases ``latent_atlas_<k>.exr`` in ``folder``, which the
    document names (module docstring). ``env_samples``: learned-sampler directions per pixel
    under environment light; ``seed`` offsets the sampled paths' random streams
    (:func:`.materialx_shader.node_source`); ``env_prefiltered`` the default of the node's input of that
    name (None: True when the networks have an environment head; True without one raises ValueError). Directions and units as :mod:`.materialx_shader`: local frame z =
    normal, x = tangent; the BSDF's response to a light is f * cos(wo) (cosine included). The emission
    and opacity come from ``surface.json`` in the export folder (for a model: in ``folder``), their maps
    copied into ``folder`` (:func:`surface_files`), and feed the surface node (:func:`add_surface_nodes`)."""
    folder = Path(folder)
    spec = as_spec(model_or_export)
    base_folder = folder if not isinstance(model_or_export, (str, Path)) else \
        (Path(model_or_export) if Path(model_or_export).is_dir() else Path(model_or_export).parent)
    tiles = _udim_tiles(model_or_export)
    codec = codec_of(model_or_export)  # block-compressed latents: DDS files, decoded into the atlases
    if latent_files is None:
        base = base_folder
        names = (latent_file_names(spec.latent_channels) if codec is None
                 else block_texture_names(spec.latent_channels))
        latent_files = [base / f for f in names]
    resolution, levels = _expected_latents(model_or_export)
    if tiles:  # every tile's files (the <UDIM> pattern, or the export's latents_<k>.<UDIM>.exr names)
        per_tile = [read_latent_files([_tile_file(f, t) for f in latent_files], spec.latent_channels, resolution,
                                      levels, codec) for t in tiles]
        layout = dataclasses.replace(per_tile[0][0], tiles=tuple(int(t) for t in tiles))
        chains = [[tile_chains[g] for _, tile_chains in per_tile] for g in range(layout.groups)]
    else:
        layout, chains = read_latent_files(latent_files, spec.latent_channels, resolution, levels, codec)
        chains = [[chain] for chain in chains]
    names = node_names(name)
    folder.mkdir(parents=True, exist_ok=True)
    surface, copies = surface_files(model_or_export, base_folder, folder)
    atlases = atlas_file_names(layout.groups)
    if env_prefiltered and not spec.environment:
        raise ValueError(f"material {name}: env_prefiltered needs networks with an environment head "
                         f"(convert with --environment-fraction above 0)")
    prefiltered = bool(spec.environment) if env_prefiltered is None else bool(env_prefiltered)
    doc = build_document(name, layout, atlases, env_samples, surface=surface, env_prefiltered=prefiltered)
    validate_document(doc, f"the MaterialX document of material {name}")
    version, source = _version(), _describe_source(model_or_export)
    texts = {names.glsl: node_source(spec, name, layout, "genglsl", file=names.glsl, nodedef=names.nodedef,
                                     version=version, source=source, seed=seed),
             names.slang: node_source(spec, name, layout, "genslang", file=names.slang, nodedef=names.nodedef,
                                      version=version, source=source, seed=seed),
             names.mtlx: mx.writeToXmlString(doc)}
    for tile_chains, atlas in zip(chains, atlases):
        write_latent_atlas(tile_chains, folder / atlas)
    for src, dest in copies:  # the emission and opacity maps, whole (module docstring)
        with atomic_path(dest) as tmp:
            shutil.copyfile(src, tmp)
    for file, text in texts.items():  # the document last: it names the other files
        with atomic_path(folder / file) as tmp:
            tmp.write_text(text)
    return folder / names.mtlx


# ------------------------------------------------------------------------------ shader generation


def load_node_document(mtlx_path):
    """The document at ``mtlx_path`` with the standard libraries as its data library."""
    doc = mx.createDocument()
    try:
        mx.readFromXmlFile(doc, str(mtlx_path))
    except Exception as exc:  # noqa: BLE001 (MaterialX raises its own exception types)
        raise InputError(f"{mtlx_path}: cannot read the MaterialX document ({exc})") from None
    doc.setDataLibrary(standard_library())
    return doc


def generation_context(generator, mtlx_path, *, environment: str = "fis", vertical_flip: bool = True,
                       max_lights: int = 1):
    """A GenContext for ``generator`` that finds the standard library sources and the node's
    implementation files beside ``mtlx_path``; ``environment`` is ``fis``, ``prefilter`` or ``none``
    (MaterialX's specular environment method), ``vertical_flip`` its fileTextureVerticalFlip option
    (True for OpenGL texture uploads with row 0 at the top, as MaterialXView)."""
    ctx = mx_gen.GenContext(generator)
    search = mx.getDefaultDataSearchPath()
    search.append(mx.FilePath(str(Path(mtlx_path).resolve().parent)))
    ctx.registerSourceCodeSearchPath(search)
    options = ctx.getOptions()
    options.hwSpecularEnvironmentMethod = {"fis": mx_gen.SPECULAR_ENVIRONMENT_FIS,
                                           "prefilter": mx_gen.SPECULAR_ENVIRONMENT_PREFILTER,
                                           "none": mx_gen.SPECULAR_ENVIRONMENT_NONE}[environment]
    options.fileTextureVerticalFlip = vertical_flip
    options.hwMaxActiveLightSources = max_lights
    options.hwShadowMap = False
    options.targetColorSpaceOverride = "lin_rec709"
    return ctx


def generate_node_shader(mtlx_path, target: str = "genglsl", material: str | None = None, **context):
    """Generate the ``target`` shader (``genglsl`` or ``genslang``) of the surfacematerial
    ``material`` (default: the document's first) in the document at ``mtlx_path``; returns
    MaterialX's Shader. ``context``: :func:`generation_context`'s options."""
    if target == "genglsl":
        generator = mx_glsl.GlslShaderGenerator.create()
    elif target == "genslang":
        generator = mx_slang.SlangShaderGenerator.create()
    else:
        raise ValueError(f"unknown target {target!r}: genglsl or genslang")
    doc = load_node_document(mtlx_path)
    nodes = doc.getMaterialNodes()
    node = doc.getNode(material) if material else (nodes[0] if nodes else None)
    if node is None:
        raise InputError(f"{mtlx_path}: no surfacematerial {material or ''} in the document")
    ctx = generation_context(generator, mtlx_path, **context)
    return generator.generate(node.getName(), node, ctx)
