"""``inspect``: what mtlx2neural would do with an asset, before any training.

For each material the scene selects: the prims bound to it, the lobes the
compiler keeps and prunes (with reasons), approximations, spatial inputs and
textures, and what a conversion with the given settings would decide
(:mod:`.plan`): the latent grid (1x1 when uniform, the textures' native grid, scaled
down to what the scene's UV texel density needs with ``--texel-density``, or capped by
``--max-texels``) with the metres of surface per UV unit measured on the bound meshes,
the source hash (``summary.json``'s cache key) and the name-free content hash, and "identical to X: trained once" for a material that would
share an earlier one's result. The geometric inputs a graph reads (position, normal, tangent,
bitangent, geomcolor, geompropvalue) are listed with where they come from: the bound mesh prims,
rasterised into their UV layout, or the unit sphere default for ``.mtlx`` input. Materials the scene skips are listed with the reason.
"""

from __future__ import annotations

from mtlx2neural.errors import InputError
from mtlx2neural.pipeline.options import InspectOptions
from mtlx2neural.pipeline.plan import plan_materials
from mtlx2neural.reference.measured import load_measured
from mtlx2neural.scene import load_asset
from mtlx2neural.train.config import preset
from mtlx2neural.train.udim import training_tiles
from mtlx2neural.universal.choice import STEPS


def inspect_asset(path, material: str | InspectOptions | None = None, allow_missing_textures: bool = False,
                  cfg=None, texel_density: float | None = None, encoder: str = "material",
                  universal_steps: int = STEPS, universal_tune: str = "networks") -> dict:
    """JSON-friendly report of ``path`` (a .mtlx file or USD stage).

    ``inspect_asset(path, options)`` takes an :class:`~mtlx2neural.pipeline.options.InspectOptions`
    (``material``, ``allow_missing_textures``, the preset and ``train`` overrides, ``texel_density``)
    in place of the separate arguments.

    ``cfg`` (default: the ``fast`` preset) is the training configuration the latent grid
    and the hashes are computed for; ``texel_density`` (latent texels per metre of surface,
    ``--texel-density``) lets the bound meshes' UV density bound the grid. Each material's
    entry adds ``latent`` (:meth:`mtlx2neural.pipeline.plan.MaterialPlan.latent_info`: ``grid``
    [H, W], ``kind`` uniform/native/density/capped, ``texture_grid`` [H, W] or None,
    ``max_texels``, ``text``, ``texel_density``, ``metres_per_uv``, ``density_texels``,
    ``density_meshes``, ``density_skipped``, ``notes``), ``source_hash``, ``content_hash``,
    ``identical_to`` (None, or the earlier material whose result it would share),
    ``encoder`` (the path it takes, :meth:`~mtlx2neural.universal.choice.EncoderChoice.record`, for
    ``encoder``, ``--encoder``), ``fallback`` (the layer's UsdPreviewSurface for it, in words) and ``warnings``.
    """

    if isinstance(material, InspectOptions):
        options = material
        material, allow_missing_textures = options.material, options.allow_missing_textures
        cfg, texel_density = options.train_config(), options.texel_density
        encoder, universal_steps, universal_tune = options.encoder, options.universal_steps, options.universal_tune
    cfg = cfg or preset("fast")
    scene = load_asset(path)
    report = {"asset": str(scene.asset), "materials": [], "skipped": [
        {"material": name, "reason": reason} for name, reason in scene.skipped]}
    sources = [src for src in scene.materials
               if not material or material in (src.name, src.name.rsplit("/", 1)[-1], src.material)]
    for plan in plan_materials(sources, cfg, allow_missing_textures, texel_density=texel_density,
                               asset=scene.asset, encoder=encoder, universal_steps=universal_steps,
                               universal_tune=universal_tune):
        src = plan.source
        info = _measured_info(src) if plan.compiled is None else plan.compiled.describe()
        info["material"] = src.name
        info["source"] = src.source_file
        info["bound_prims"] = list(src.bound_prims)
        info["latent"] = plan.latent_info()
        info["source_hash"], info["content_hash"] = plan.digest, plan.content
        info["identical_to"] = plan.shared_with
        info["encoder"] = plan.encoder.record()
        info["fallback"] = ("the input's own UsdPreviewSurface, kept as authored" if getattr(src, "preview_surface", False)
                            else "none (--preview-iterations 0)" if cfg.preview_iterations == 0
                            else f"a UsdPreviewSurface fitted in {cfg.preview_iterations} steps")
        info["warnings"] = list(plan.warnings)
        # the UDIM tiles a conversion trains (None: no UDIM set), with why, as train.udim decides them
        info["udim_tiles"], info["udim_notes"] = (None, []) if plan.compiled is None else training_tiles(
            plan.compiled, getattr(src, "stage_file", None), src.bound_prims)
        report["materials"].append(info)
    if material and not report["materials"] and not any(
            material in (name, name.rsplit("/", 1)[-1]) for name, _ in scene.skipped):
        listing = "\n".join([f"  {src.name}" for src in scene.materials]
                            + [f"  {name}  ({reason})" for name, reason in scene.skipped])
        raise InputError(f"{scene.asset}: no material named {material!r}. "
                         f"Available materials:\n{listing or '  (none)'}")
    return report


def _measured_info(src) -> dict:
    """``describe()``'s fields for a measured BRDF: one tabulated lobe, nothing spatial."""
    table = load_measured(src.source_file).describe()
    return {"lobes_kept": [{"closure": "measured (MERL table)", "node": src.source_file}], "lobes_pruned": [],
            "approximations": [f"isotropic table {'x'.join(map(str, table['dims']))} read with "
                               f"{table['interpolation']} interpolation; {table['unmeasured_entries']} unmeasured "
                               f"entries read as 0"],
            "spatial_inputs": [], "textures": [], "varying_parameters": [], "measured": table}


_SURFACE_KIND = {"constant": "kept (a constant)", "textured": "kept (a map beside the latents)"}


def _surface_lines(surface: dict | None, pruned: list[dict]) -> list[str]:
    """The channels kept beside the BRDF: emission and opacity (kept, not approximated), and that
    transmission through glass is not modelled when a transmission lobe was pruned."""
    if not surface:
        return []
    lines = ["  beside the BRDF:",
             f"    emission   {_SURFACE_KIND.get(surface['emission'], 'none')}",
             f"    opacity    {_SURFACE_KIND.get(surface['opacity'], 'none (opaque)')}"]
    if any("transmission" in p["reason"] for p in pruned):
        lines.append("    transmission (refraction through glass) is not modelled: out of scope")
    return lines


def format_report(report: dict) -> str:
    """Human-readable text for :func:`inspect_asset`'s result."""
    lines = [f"asset: {report['asset']}"]
    for m in report["materials"]:
        lines.append(f"\nmaterial {m['material']}  ({m['source']})")
        if m["bound_prims"]:
            lines.append(f"  bound prims: {', '.join(m['bound_prims'])}")
        lines.append("  lobes kept:")
        lines += [f"    {k['closure']:<26} {k['node']}" for k in m["lobes_kept"]] or ["    (none: black)"]
        if m["lobes_pruned"]:
            lines.append("  lobes pruned:")
            lines += [f"    {k['closure']:<26} {k['node']}\n      why: {k['reason']}" for k in m["lobes_pruned"]]
        lines += _surface_lines(m.get("surface"), m["lobes_pruned"])
        if m["approximations"]:
            lines.append("  approximations:")
            lines += [f"    - {a}" for a in m["approximations"]]
        if m["spatial_inputs"] or m["textures"]:
            lines.append("  spatially varying:")
            lines += [f"    {s['kind']:<12} {s['node']}" for s in m["spatial_inputs"]]
            lines += [f"    texture      {t['file']}  [{t['colorspace'] or 'raw'}]  ({t['node']})" for t in m["textures"]]
            lines += [f"    parameter    {p}" for p in m["varying_parameters"]]
        else:
            lines.append("  spatially uniform: a single latent code suffices")
        if m.get("geometry_inputs"):
            lines.append("  geometric inputs:")
            lines += [f"    {g['kind']:<12} {g.get('space') or 'primvar ' + g.get('primvar', '')}  ({g['node']})"
                      f"  from {g['source']}" for g in m["geometry_inputs"]]
        if "latent" in m:
            lines.append(f"  latent grid: {m['latent']['text']}")
            if m.get("udim_tiles"):
                lines.append(f"  UDIM tiles trained: {', '.join(map(str, m['udim_tiles']))} (one latent grid each; "
                             f"the bound meshes' tiles, else every tile on disk)")
                lines += [f"    note: {n}" for n in m.get("udim_notes", [])]
            lines += _density_lines(m["latent"])
            if m.get("encoder"):
                lines.append(f"  network: {m['encoder']['text']}")
            if m.get("fallback"):
                lines.append(f"  fallback: {m['fallback']}")
            lines.append(f"  source hash: {m['source_hash'][:12]}  (content {m['content_hash'][:12]})")
            if m["identical_to"]:
                lines.append(f"  identical to {m['identical_to']}: trained once (same compiled graph, textures "
                             f"and settings), this material shares its result")
            lines += [f"  warning: {w}" for w in m["warnings"]]
            lines += [f"  note: {n}" for n in m["latent"].get("notes", [])]
    if report["skipped"]:
        lines.append("\nskipped:")
        lines += [f"  {s['material']}: {s['reason']}" for s in report["skipped"]]
    return "\n".join(lines)


def _density_lines(latent: dict) -> list[str]:
    """The texel density's measure: metres per UV unit (per mesh when several) and the prims left out."""
    meshes, lines = latent.get("density_meshes") or [], []
    if latent.get("metres_per_uv") is not None:
        unit = f"metersPerUnit {latent['meters_per_unit']:g}" + (
            "" if latent["meters_per_unit_authored"] else ", unauthored: USD's default, centimetres")
        lines.append(f"  texel density: {latent['metres_per_uv']:.4g} m of surface per UV unit ({unit}) x "
                     f"{latent['texel_density']:g} texels/m = {latent['density_texels']} texels per UV unit: "
                     f"{latent['kind']} grid")
        if len(meshes) > 1:
            lines += [f"    {k['prim']}: {k['metres_per_uv']:.4g} m per UV unit" for k in meshes]
    lines += [f"    not measured: {k['prim']}: {k['reason']}" for k in latent.get("density_skipped") or []]
    return lines
