"""``mtlx2neural render ASSET -o OUT.exr``: render one material, reference or neural, to an EXR and a
PNG (:class:`~mtlx2neural.report.options.RenderOptions`)."""

from __future__ import annotations

import argparse

from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.errors import InputError
from mtlx2neural.report.options import RenderOptions

NAME = "render"
USAGE = "mtlx2neural render ASSET -o OUT.exr"
HELP = "render one material (reference or neural) to an EXR and a PNG"


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}.")
    p.add_argument("asset", metavar="ASSET", help=".mtlx file, USD stage (.usda/.usdc/.usd/.usdz), MERL .binary, or the "
                   "neural layer that mtlx2neural ASSET wrote (<asset stem>_neural.usda)")
    add_options(p, RenderOptions)
    return p


def run(args: argparse.Namespace) -> int:
    options = options_from_args(RenderOptions, args)
    if options.renderer == "mitsuba":
        return _run_mitsuba(args.asset, options)
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.report.views import render_asset

    s = render_asset(args.asset, options)
    model = s["model"] if s["neural_source"] is None else f"{s['model']}, from the {s['neural_source']} {s['neural_path']}"
    tile = f" as UDIM tile {s['tile']}" if s.get("tile") is not None else ""
    print(f"{s['material']} ({model}): {s['geometry']}{tile} under {s['env']} (MIS: {s['mis']}), {s['res']}x{s['res']}, "
          f"{s['spp']} spp in {s['seconds']} s; wrote {s['exr']} and {s['png']}")
    return 0


def _run_mitsuba(asset, options: RenderOptions) -> int:
    """``--renderer mitsuba``: :func:`mtlx2neural.mitsuba.render.render_stage`, or exit 2 naming what to install."""
    # Local: the Mitsuba component is optional; its probe imports nothing heavy.
    from mtlx2neural.mitsuba import mitsuba_missing

    reason = mitsuba_missing()
    if reason is not None:
        raise InputError(f"--renderer mitsuba: {reason}")
    # Local: optional (Mitsuba, Dr.Jit), and --help answers without importing torch.
    from mtlx2neural.mitsuba.render import render_stage

    s = render_stage(asset, options)
    drawn = ", ".join(f"{prim} ({how})" for prim, how in s["materials"].items())
    print(f"{drawn}: model {s['model']} in Mitsuba, {s['res']}x{s['res']}, {s['spp']} spp, max depth {s['max_depth']} "
          f"in {s['seconds']} s; wrote {s['exr']} and {s['png']}" + (f" ({len(s['notes'])} notes)" if s["notes"] else ""))
    return 0
