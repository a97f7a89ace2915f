"""The record of one material's conversion: :class:`MaterialRecord`, stored as ``summary.json``.

Training writes it into the material's folder (``OUT/<material folder>/summary.json``), the
conversion adds how the result was obtained (reused, shared) and where the layer went, the
layer's ``neural:metrics:*`` attributes come from :meth:`MaterialRecord.layer_metrics`, and
``report``, ``render`` and a later run's cache check read it back with :func:`read_record`.

The file is a flat JSON object: one key per field of :class:`MaterialRecord`, plus
``record_version``. A file whose version is not :data:`RECORD_VERSION` (a record written by another
version of the tool, or with no version at all), that is not JSON, or whose keys do not match the
fields raises :class:`RecordError`, which names the file and says what to do.

Units: seconds are wall-clock seconds; every ``flip*`` figure is HDR FLIP (0 = identical, 1 = the
largest difference), averaged as its field says.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError

RECORD_FILE = "summary.json"
"""File name of the record in a material's folder."""
RECORD_VERSION = 5
"""Version of the record's layout; bumped whenever a field is added, removed or changes meaning."""


class RecordError(InputError):
    """A ``summary.json`` that cannot be read as this version's :class:`MaterialRecord` (exit 2)."""


@dataclass
class MaterialRecord:
    """What one material's conversion produced: identity, settings, timings, quality figures, notes."""

    # --- identity: which material, from which input
    material: str
    """USD Material prim path, or the surfacematerial name for ``.mtlx`` input."""
    mtlx_material: str
    """The surfacematerial node in the MaterialX document."""
    source: str
    """The input file the material was read from (absolute path)."""
    source_hash: str
    """Cache key (:func:`mtlx2neural.pipeline.plan.cache_key`): same key, same training result."""
    bound_prims: list[str] = field(default_factory=list)
    """Prim paths of the meshes bound to the material (empty for ``.mtlx`` input)."""
    content_hash: str = ""
    """Name-free hash of the compiled graph, textures and settings: equal for identical materials."""
    input_hash: str | None = None
    """Hash of the material's document and every file it reads, to tell a kept material went stale."""

    # --- settings the model was trained with
    decoder: str = ""
    """Decoder size trained (``TrainConfig.decoder``; an error budget's choice)."""
    config: dict = field(default_factory=dict)
    """``dataclasses.asdict(TrainConfig)`` of the training: ``TrainConfig(**config)`` rebuilds it."""
    resolution: list[int] = field(default_factory=list)
    """Latent grid of the finest level, (height, width) in texels (per UDIM tile)."""
    varying_channels: int = 0
    """Parameter channels that vary over the surface (textured inputs)."""
    latent: dict | None = None
    """The plan's grid decision (:meth:`mtlx2neural.pipeline.plan.MaterialPlan.latent_info`)."""
    options: dict | None = None
    """The conversion's options (:func:`mtlx2neural.pipeline.options.options_record`)."""
    udim_tiles: list[int] | None = None
    """UDIM tiles trained (1001, ...), or None for a material without UDIM textures."""
    application: dict | None = None
    """The instant ``time``/``frame`` nodes were folded at: ``frame``, ``fps``, ``time`` (seconds) and
    ``nodes`` (the nodes that read it); None when the graph reads neither."""

    # --- the training run
    steps: int = 0
    """Adam steps trained."""
    seconds: float = 0.0
    """Wall-clock seconds of the whole job: training, measurement, preview fit (an error budget: every
    size tried)."""
    train_seconds: float = 0.0
    """Wall-clock seconds of the neural model's training alone (the layer's ``trainSeconds``)."""
    final_loss_brdf: float = float("nan")
    """The last step's BRDF loss (log-L1 of cosine-weighted BRDF values)."""
    held_out_log_l1: float = float("nan")
    """Log-L1 error of the cosine-weighted BRDF on held-out directions and texels."""
    device: str = ""
    """torch device trained on (``cpu``, ``cuda:0``)."""
    device_name: str = ""
    """The device in words: ``cpu (x86_64)``, ``cuda:0 (<GPU name>)``."""
    threads: int = 0
    """torch threads of the training process."""
    worker: str = ""
    """``host:pid`` of the process that trained."""

    # --- quality: the neural model against the reference BRDF
    flip_mean: float = float("nan")
    """Mean HDR FLIP over the analytic views (sphere renders: three directional, one under the sky;
    :mod:`mtlx2neural.render.summary_views`)."""
    flip_per_view: list[float] = field(default_factory=list)
    """HDR FLIP of each analytic view (tile by tile for a UDIM material)."""
    flip_views: list[str] = field(default_factory=list)
    """How each analytic view was made, in the order of ``flip_per_view`` (per tile)."""
    flip_viewer: float | None = None
    """HDR FLIP of the environment view shaded as a viewer shades it: the model's prefiltered environment path
    (the MaterialX node's and ``shadeEnvironment``'s default) against the reference's render
    (:func:`mtlx2neural.render.summary_views.viewer_view`); not part of ``flip_mean``. None for a model
    without an environment head, a UDIM material, or an older record."""
    flip_viewer_view: str = ""
    """How ``flip_viewer`` was made."""
    relmse_mean: float = float("nan")
    """Mean relative MSE over the analytic views."""
    flip_per_tile: dict[str, float] | None = None
    """Mean HDR FLIP of each UDIM tile's views (tile number as a string), for a UDIM material."""
    flip_in_scene: float | None = None
    """HDR FLIP over the pixels showing the bound meshes, rendered with the stage's camera and lights;
    None when there is no stage to render (``in_scene`` says why)."""
    preview_flip_in_scene: float | None = None
    """``flip_in_scene`` of the UsdPreviewSurface fallback (the analytic baseline)."""
    in_scene: dict | None = None
    """How the in-scene figure was measured: ``measured``, camera, lights, prims, resolution,
    samples, coverage, seconds, or ``why`` not."""
    energy: dict | None = None
    """The energy check (:func:`mtlx2neural.verify.energy.energy_check`): ``min_ratio`` and ``by_level``,
    the neural model's directional albedo over the reference's per MIP level (1 keeps the energy),
    ``by_view`` the same per view angle averaged over the levels (absent from older records), with the
    settings it was measured with; None when not measured (a UDIM material)."""
    quality: dict | None = None
    """The run's quality gate (:mod:`mtlx2neural.pipeline.quality`): ``flagged``, ``reasons`` (in words) and
    ``policy`` (``ConvertOptions.flagged``: what the layer does with a flagged material); None before the
    gate has run."""
    surface: dict | None = None
    """Emission and opacity beside the BRDF (:meth:`mtlx2neural.textures.surface_maps.SurfaceMaps.describe`:
    ``emission`` none/constant/texture, ``alpha_mode`` opaque/mask/blend, ``coverage``) and the
    direction-dependent EDFs ``refused``; None before it was recorded."""
    preview_flip: float | None = None
    """Mean HDR FLIP of the UsdPreviewSurface fallback over the analytic views; None without one."""
    preview: dict | None = None
    """The fallback's fit: ``model``, ``file``, ``iterations``, ``flip_per_view``, ``fit_seconds``."""
    budget: dict | None = None
    """With an error budget: ``max_error``, ``metric`` (the figure checked), ``flip_by_decoder``,
    ``seconds_by_decoder`` and ``met``."""
    budget_met: bool | None = None
    """Whether the error budget was met; None without a budget."""
    notes: list[str] = field(default_factory=list)
    """What the conversion decided or approximated, in words."""
    warnings: list[str] = field(default_factory=list)
    """What a user should act on (a missed budget, a capped grid, an HDR FLIP computed on a black view)."""

    # --- how the conversion obtained it
    network: dict | None = None
    """With ``--network scene``: the group sharing this material's decoder and sampler (``materials``), the
    ``joint_steps``, ``rows_per_material`` per joint step, the ``latent_steps`` of each material's own
    fine-tune, and the phases' wall ``seconds`` (``joint``, ``latents``, ``environment``); None for a
    network of its own."""
    encoder: dict | None = None
    """With ``--encoder universal``, the material's path (:meth:`~mtlx2neural.universal.choice.EncoderChoice.record`:
    ``path`` universal, the shading ``model``, the latent fine-tune's ``steps``, the shipped weights'
    ``weights_sha256``); None when it trained its own network."""
    shared_with: str | None = None
    """The material whose training this one reuses, being identical to it; None when trained itself."""
    cached: bool = False
    """True when an earlier run's result was reused unchanged."""
    usd: str | None = None
    """The neural layer the material was exported into (set by the conversion after export)."""
    export_notes: list[str] = field(default_factory=list)
    """FP16 range and export notes of the material's files."""

    # ------------------------------------------------------------------ derived figures

    def budget_error(self) -> float:
        """The HDR FLIP an error budget is checked against: ``flip_in_scene`` when measured, else
        ``flip_mean``."""
        return self.flip_in_scene if self.flip_in_scene is not None else self.flip_mean

    def layer_metrics(self, preset: str) -> dict:
        """The layer's ``neural:metrics:*`` values (flip, iterations, preset, device, train_seconds,
        preview_flip, flip_in_scene)."""
        return {"flip": self.flip_mean, "iterations": self.steps, "preset": preset,
                "device": self.device_name or self.device, "train_seconds": self.train_seconds,
                "preview_flip": self.preview_flip, "flip_in_scene": self.flip_in_scene}

    def with_warning(self, warning: str) -> MaterialRecord:
        """A copy with ``warning`` in ``warnings`` and first in ``notes``."""
        return dataclasses.replace(self, warnings=[*self.warnings, warning], notes=[warning, *self.notes])

    # ------------------------------------------------------------------ JSON

    def to_json(self) -> dict:
        """The JSON object of ``summary.json``: every field, and ``record_version``."""
        return {"record_version": RECORD_VERSION, **dataclasses.asdict(self)}

    @classmethod
    def from_json(cls, data, where: str | Path) -> MaterialRecord:
        """The record in ``data`` (a parsed ``summary.json``); :class:`RecordError` naming ``where``
        when its version or keys do not match this version's record."""
        if not isinstance(data, dict):
            raise RecordError(f"{where}: not a material record (a JSON object is expected)")
        version = data.get("record_version")
        if version != RECORD_VERSION:
            was = "no record_version" if version is None else f"record_version {version}"
            raise RecordError(f"{where}: written by another version of mtlx2neural ({was}; this one reads "
                              f"{RECORD_VERSION}); convert the asset again (--force) to rewrite it")
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - fields - {"record_version"})
        missing = sorted(f.name for f in dataclasses.fields(cls)
                         if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
                         and f.name not in data)
        if unknown or missing:
            what = "; ".join(([f"unknown keys {unknown}"] if unknown else [])
                             + ([f"missing keys {missing}"] if missing else []))
            raise RecordError(f"{where}: not a valid material record ({what}); convert the asset again (--force)")
        return cls(**{k: v for k, v in data.items() if k != "record_version"})


def record_path(folder: str | Path) -> Path:
    """``folder/summary.json``."""
    return Path(folder) / RECORD_FILE


def read_record(folder: str | Path) -> MaterialRecord:
    """The record in ``folder`` (a material folder); :class:`RecordError` naming the file when it is
    unreadable, not JSON, or not this version's record (:meth:`MaterialRecord.from_json`)."""
    path = record_path(folder)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RecordError(f"{path}: cannot read the material record: {exc.strerror or exc}") from exc
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise RecordError(f"{path}: not JSON ({exc}); convert the asset again (--force)") from exc
    return MaterialRecord.from_json(data, path)


def read_record_or_none(folder: str | Path) -> MaterialRecord | None:
    """:func:`read_record`, or None when there is no readable record of this version (a cache check:
    such a folder trains again)."""
    try:
        return read_record(folder)
    except RecordError:
        return None


def write_record(folder: str | Path, record: MaterialRecord) -> Path:
    """Write ``record`` to ``folder/summary.json`` atomically; returns the path."""
    path = record_path(folder)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(record.to_json(), indent=2, allow_nan=True) + "\n")
    return path
