"""``inspect``: what mtlx2neural would do with an asset, before any training.

For each material the scene selects: the prims bound to it, the lobes the
compiler keeps and prunes (with reasons), approximations, spatial inputs and
textures. Materials the scene skips are listed with the reason.
"""

from __future__ import annotations

from .errors import InputError
from .graph import compile_material
from .scene import load_asset


def inspect_asset(path, material: str | None = None, allow_missing_textures: bool = False) -> dict:
    """JSON-friendly report of ``path`` (a .mtlx file or USD stage)."""
    scene = load_asset(path)
    report = {"asset": str(scene.asset), "materials": [], "skipped": [
        {"material": name, "reason": reason} for name, reason in scene.skipped]}
    for src in scene.materials:
        if material and material not in (src.name, src.name.rsplit("/", 1)[-1], src.material):
            continue
        info = compile_material(src.document, src.material,
                                allow_missing_textures=allow_missing_textures).describe()
        info["material"] = src.name
        info["source"] = src.source_file
        info["bound_prims"] = list(src.bound_prims)
        report["materials"].append(info)
    if material and not report["materials"] and not any(
            material in (name, name.rsplit("/", 1)[-1]) for name, _ in scene.skipped):
        listing = "\n".join([f"  {src.name}" for src in scene.materials]
                            + [f"  {name}  ({reason})" for name, reason in scene.skipped])
        raise InputError(f"{scene.asset}: no material named {material!r}. "
                         f"Available materials:\n{listing or '  (none)'}")
    return report


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
    if report["skipped"]:
        lines.append("\nskipped:")
        lines += [f"  {s['material']}: {s['reason']}" for s in report["skipped"]]
    return "\n".join(lines)
