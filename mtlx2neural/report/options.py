"""Options of ``mtlx2neural render`` (:class:`RenderOptions`, for
:func:`mtlx2neural.report.views.render_asset`) and ``mtlx2neural report`` (:class:`ReportOptions`,
for :func:`mtlx2neural.report.html_report.write_report`).

As with :class:`mtlx2neural.pipeline.options.ConvertOptions`, each field's docstring is its
documentation (the command line's help and docs/cli.md's option table) and ``metadata`` gives the flag
where it differs from ``--field-name``, a metavar or the choices. Field names are the keyword
arguments of the function the options are for (:meth:`RenderOptions.kwargs`,
:meth:`ReportOptions.kwargs`). This module imports nothing heavy: the command line's ``--help``
reads it without torch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from mtlx2neural.errors import InputError


def _kwargs(options) -> dict:
    """The fields of ``options`` by name (shallow: values are not copied)."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}


@dataclass
class RenderOptions:
    """Options of one render (``mtlx2neural render ASSET`` / ``render_asset(asset, options)``)."""

    output: str = field(metadata={"flag": "-o/--output", "metavar": "OUT.exr"})
    """The linear (float32) EXR to write, in an existing folder; an sRGB PNG (exposure 1) is
    written beside it."""
    material: str | None = field(default=None, metadata={"metavar": "M"})
    """USD prim path, prim name or MaterialX material name (may be left out when the asset selects
    exactly one)."""
    model: str = field(default="reference", metadata={"choices": ("reference", "neural")})
    """reference (the MaterialX reference BRDF) or neural: read from the exported layer and its files
    when ASSET is the ``*_neural.usda`` layer or that layer lies beside ASSET, else from the training
    checkpoint."""
    checkpoint: str | None = field(default=None, metadata={"metavar": "PATH"})
    """Render the neural model of this ``checkpoint.pt`` (or its folder) instead of the exported layer
    (default, when no layer records the material: ``<asset stem>_neural/<material folder>/checkpoint.pt``
    beside the asset)."""
    geometry: str = "sphere"
    """sphere, plane, teapot (MaterialX's ``resources/Geometry/teapot.obj``) or a path to an .obj."""
    env: str = "sky"
    """``sky`` (a procedural sky) or a lat-long .hdr/.exr environment map."""
    res: int = field(default=256, metadata={"metavar": "PIXELS"})
    """Image width and height, in pixels."""
    spp: int = field(default=16, metadata={"metavar": "N"})
    """Samples per pixel (one light sample each, plus one BSDF sample with ``mis = own``)."""
    mis: str = field(default="own", metadata={"choices": ("own", "none")})
    """own: also one sample of the model's own BSDF sampler per pass, combined with the light
    sample by MIS; none: light samples only, every random number shared between models."""
    azimuth: float = field(default=30.0, metadata={"metavar": "DEG"})
    """Camera azimuth, degrees: 0 looks from +z, 90 from +x."""
    elevation: float = field(default=20.0, metadata={"metavar": "DEG"})
    """Camera elevation above the horizon, degrees."""
    distance: float = field(default=4.0, metadata={"metavar": "RADII"})
    """Camera distance from the centre, in bounding-sphere radii (more than 1)."""
    fov: float = field(default=30.0, metadata={"metavar": "DEG"})
    """Vertical field of view, degrees (between 0 and 180)."""
    seed: int = field(default=0, metadata={"metavar": "N"})
    """Seed of the render's random numbers: a reference and a neural render with the same seed share
    their light samples."""
    env_mode: str = field(default="sampled", metadata={"choices": ("sampled", "prefiltered")})
    """sampled: the environment by Monte Carlo (light samples, plus --mis); prefiltered: a neural model
    with an environment head shades it from its learned lobes' prefiltered lookups, without noise, as
    the MaterialX node does (the reference, and models without the head, stay sampled)."""
    allow_missing_textures: bool = False
    """Use an image node's declared default when its file is missing, instead of failing."""
    frame: float | None = field(default=None, metadata={"metavar": "F"})
    """The instant the reference's ``frame``/``time`` nodes fold to (as ``convert --frame``); default:
    the one the asset's conversion used (its ``summary.json``), else frame 1."""
    fps: float | None = field(default=None, metadata={"metavar": "R"})
    """Frames per second that turn ``--frame`` into the ``time`` node's seconds; default: the
    conversion's, else 24."""
    tile: int | None = field(default=None, metadata={"metavar": "UDIM"})
    """UDIM tile (1001, 1002, ...) the geometry shows, its uv wrapped into the tile (frac(uv) plus the
    tile's origin): for a UDIM material. Default: the neural model's first trained tile; the reference
    reads the geometry's own uv (tile 1001)."""
    renderer: str = field(default="torch", metadata={"choices": ("torch", "mitsuba")})
    """torch: this tool's renderer, one material on --geometry under --env (direct light, no shadows).
    mitsuba: the whole USD stage in Mitsuba 3's path tracer (shadows, interreflections up to
    --max-depth), every material of the neural layer bound to its Mitsuba plugin (mtlx_neural or
    mtlx_reference, per --model), seen by the stage's camera under its lights (--material: that
    material's meshes only); needs the optional Mitsuba component (pip install "mtlx2neural[mitsuba]").
    --geometry, --env, --mis, --azimuth, --elevation, --distance, --fov, --tile, --frame, --fps and
    --checkpoint are the torch renderer's (Mitsuba's reference reads the conversion's frame)."""
    max_depth: int = field(default=3, metadata={"metavar": "N"})
    """Mitsuba's longest path, in surface interactions (--renderer mitsuba; at least 3): 1 shows the
    emitters, 2 adds direct light, 3 one bounce more; passing through a cut-out counts as one."""

    MITSUBA_ONLY = ("renderer", "max_depth")
    """Fields that :func:`~mtlx2neural.report.views.render_asset` does not take: they select and set up the
    Mitsuba renderer (:func:`mtlx2neural.mitsuba.render.render_stage`)."""

    def kwargs(self) -> dict:
        """The keyword arguments of :func:`~mtlx2neural.report.views.render_asset` after ``asset``: every field
        but :attr:`MITSUBA_ONLY` (``render_asset`` is the torch renderer; the report layer cannot import the
        Mitsuba component, which ranks above it). ``renderer="mitsuba"`` raises
        :class:`~mtlx2neural.errors.InputError` naming :func:`mtlx2neural.mitsuba.render.render_stage`, so those
        options never render silently with torch."""
        if self.renderer != "torch":
            raise InputError(f"renderer {self.renderer!r}: render_asset renders with the torch renderer; render "
                             f"with Mitsuba through mtlx2neural.mitsuba.render.render_stage(asset, options) "
                             f"(mtlx2neural render ASSET --renderer mitsuba)")
        return {k: v for k, v in _kwargs(self).items() if k not in self.MITSUBA_ONLY}


@dataclass
class ReportOptions:
    """Options of one HTML report (``mtlx2neural report LAYER`` / ``write_report``)."""

    out: str | None = field(default=None, metadata={"flag": "-o/--output", "metavar": "DIR"})
    """Report folder (default: ``<layer stem>_report`` beside the layer); it appears complete, or
    not at all."""
    analytic_iterations: int = field(default=300, metadata={"metavar": "N"})
    """Adam steps of the analytic (Lambert + GGX) baseline fit."""
    res: int = field(default=96, metadata={"metavar": "PIXELS"})
    """Render width and height, in pixels."""
    spp: int = field(default=8, metadata={"metavar": "N"})
    """Samples per pixel of the renders."""
    seed: int = field(default=0, metadata={"metavar": "N"})
    """Seed of the analytic baseline's fit and of the scene view's renders."""
    scene_res: int = field(default=128, metadata={"metavar": "PIXELS"})
    """Width and height, in pixels, of the scene view (a USD input's whole stage from its camera, every
    material of the layer at once: reference, neural, UsdPreviewSurface preview); 0 leaves the scene view out."""
    scene_spp: int = field(default=16, metadata={"metavar": "N"})
    """Samples per pixel of the scene view's renders."""
    materials: list[str] | None = field(default=None, metadata={"flag": "--material", "metavar": "M"})
    """Only this material (prim path or name); repeat the flag for several (default: every neural
    material of the layer)."""
    texels_at: list[tuple[float, float]] | None = field(default=None, metadata={"flag": "--texel",
                                                                                "metavar": "U,V"})
    """Texture coordinate of the polar plots of the BRDF and the sampler's pdf; repeat the flag for
    several (default: 0.5,0.5)."""
    train_sizes: bool = False
    """Train the decoder sizes (2x16, 2x32, 3x64) the conversion did not, with its settings, so that
    error versus cost shows every size (minutes per size)."""

    def kwargs(self) -> dict:
        """The keyword arguments of :func:`~mtlx2neural.report.html_report.write_report` after ``layer``."""
        return _kwargs(self)
