"""``mtlx2neural report LAYER``: the HTML report of a neural layer
(:class:`~mtlx2neural.report.options.ReportOptions`)."""

from __future__ import annotations

import argparse

from mtlx2neural.commands import values
from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.report.options import ReportOptions

NAME = "report"
USAGE = "mtlx2neural report LAYER"
HELP = ("HTML report of a neural layer: the whole scene (USD input), renders, FLIP, analytic baseline, error "
        "versus cost, polar plots, training curves, latents, memory")


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}.")
    p.add_argument("layer", metavar="LAYER",
                   help="the neural USD layer that `mtlx2neural ASSET` wrote (ASSET_neural.usda)")
    add_options(p, ReportOptions, parsers={"texels_at": values.uv})
    return p


def run(args: argparse.Namespace) -> int:
    options = options_from_args(ReportOptions, args)
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.report.html_report import write_report

    r = write_report(args.layer, **options.kwargs())
    scene = r["scene"]
    if isinstance(scene, dict):
        t = scene["totals"]
        print(f"scene: HDR FLIP neural {scene['flip']['neural']:.4f}, preview {scene['flip']['preview']:.4f}; "
              f"{t['converted']} converted ({t['flagged']} flagged), {t['skipped']} skipped; shipped "
              f"{t['shipped_memory']:,} bytes against {t['source_textures']:,} bytes of source textures")
    else:
        print(f"scene: none ({scene})")
    for m in r["materials"]:
        print(f"{m['material']}: HDR FLIP neural {m['flip']['neural']:.4f}, analytic {m['flip']['analytic']:.4f}")
    print(f"wrote {r['html']}")
    return 0
