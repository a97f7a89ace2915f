"""Command line: a thin shell over the library API.

    mtlx2neural ASSET [-o OUT] [--preset fast|balanced|paper] [--decoder 2x16|2x32|3x64] [--force] ...
    mtlx2neural inspect ASSET [--material M] [--json]
    mtlx2neural render ASSET [--material M] [--model reference|neural] [--checkpoint PATH]
                       [--geometry sphere|plane|teapot|FILE.obj] [--env sky|FILE.hdr] -o OUT.exr

Exit codes: 0 ok, 1 failure, 2 bad input (the message names the file, prim or
node and what to do).
"""

from __future__ import annotations

import argparse
import json
import sys

from .errors import Mtlx2NeuralError

SUBCOMMANDS = ("inspect", "convert", "render")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mtlx2neural", description="Bake MaterialX materials into neural materials.")
    sub = p.add_subparsers(dest="command", required=True)
    ins = sub.add_parser("inspect", help="list materials, bound prims, kept/pruned lobes, spatial inputs, textures")
    ins.add_argument("asset", help=".mtlx file or USD stage (.usda/.usdc/.usd)")
    ins.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    ins.add_argument("--json", action="store_true", help="print JSON instead of text")
    ins.add_argument("--allow-missing-textures", action="store_true",
                     help="use an image node's declared default when its file is missing")
    conv = sub.add_parser("convert", help="train a neural material for every selected material (default command)")
    conv.add_argument("asset", help=".mtlx file or USD stage")
    conv.add_argument("-o", "--output", help="output folder (default: ASSET_neural next to the input); "
                                             "the USD layer is written beside it as <folder>.usda")
    conv.add_argument("--preset", default="fast", choices=["fast", "balanced", "paper"])
    conv.add_argument("--decoder", choices=["2x16", "2x32", "3x64"])
    conv.add_argument("--iterations", type=int)
    conv.add_argument("--batch", type=int)
    conv.add_argument("--frames", type=int)
    conv.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    conv.add_argument("--device", default="auto", help="cpu, cuda or auto (CUDA when present)")
    conv.add_argument("--seed", type=int)
    conv.add_argument("--resume", action="store_true", help="continue from the checkpoints in the output folder")
    conv.add_argument("--force", action="store_true",
                      help="retrain every material, even one unchanged since the last run (same source hash)")
    conv.add_argument("--allow-missing-textures", action="store_true")
    conv.add_argument("--quiet", action="store_true", help="no progress bar")
    ren = sub.add_parser("render", help="render one material (reference or neural) to an EXR and a PNG")
    ren.add_argument("asset", help=".mtlx file or USD stage")
    ren.add_argument("-o", "--output", required=True, help="output .exr (a .png is written beside it)")
    ren.add_argument("--material", help="prim path, prim name or MaterialX name")
    ren.add_argument("--model", default="reference", choices=["reference", "neural"])
    ren.add_argument("--checkpoint", help="neural checkpoint.pt or its folder "
                                          "(default: ASSET_neural/<material>/checkpoint.pt)")
    ren.add_argument("--geometry", default="sphere", help="sphere, plane, teapot or a path to an .obj")
    ren.add_argument("--env", default="sky", help="'sky' (procedural) or a lat-long .hdr/.exr environment map")
    ren.add_argument("--res", type=int, default=256, help="image width and height in pixels")
    ren.add_argument("--spp", type=int, default=16, help="samples per pixel (one light sample each)")
    ren.add_argument("--azimuth", type=float, default=30.0, help="degrees; 0 looks from +z, 90 from +x")
    ren.add_argument("--elevation", type=float, default=20.0, help="degrees above the horizon")
    ren.add_argument("--distance", type=float, default=4.0, help="camera distance in bounding-sphere radii")
    ren.add_argument("--fov", type=float, default=30.0, help="vertical field of view, degrees")
    ren.add_argument("--seed", type=int, default=0)
    ren.add_argument("--allow-missing-textures", action="store_true")
    return p


def _render(args) -> int:
    from .evaluate.render_cli import render_asset

    s = render_asset(args.asset, args.output, args.material, args.model, args.checkpoint, args.geometry,
                     args.env, args.res, args.spp, args.azimuth, args.elevation, args.distance, args.fov,
                     args.seed, args.allow_missing_textures)
    print(f"{s['material']} ({s['model']}): {s['geometry']} under {s['env']}, {s['res']}x{s['res']}, "
          f"{s['spp']} spp in {s['seconds']} s; wrote {s['exr']} and {s['png']}")
    return 0


def _convert(args) -> int:
    from .convert import convert_asset, default_output
    from .train.config import preset
    from .train.trainer import TrainingInterrupted

    cfg = preset(args.preset, decoder=args.decoder, iterations=args.iterations, batch=args.batch,
                 frames=args.frames, seed=args.seed)
    try:
        summaries = convert_asset(args.asset, cfg, args.output, args.material, args.device, args.resume,
                                  not args.quiet, args.allow_missing_textures, force=args.force,
                                  preset=args.preset)
    except TrainingInterrupted as exc:
        print(f"mtlx2neural: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the export could not write its files; nothing partial was left
        print(f"mtlx2neural: error: cannot write the output ({exc}); nothing was exported", file=sys.stderr)
        return 1
    out = args.output or default_output(args.asset)
    for s in summaries:
        how = "reused (unchanged; --force retrains)" if s["cached"] else f"{s['steps']} steps in {s['seconds']} s"
        print(f"{s['material']}: {how}, held-out log-L1 "
              f"{s['held_out_log_l1']:.4f}, HDR FLIP {s['flip_mean']:.4f} (views {s['flip_per_view']})")
        notes = s.get("export_notes", [])
        for note in notes[:3]:
            print(f"  fp16: {note}")
        if len(notes) > 3:
            print(f"  fp16: ... and {len(notes) - 3} more (see neural/weights.json and export.json)")
    print(f"wrote {out} (checkpoints, training curves, summaries, latent EXRs, weights)")
    if summaries:
        print(f"wrote {summaries[0]['usd']} (USD layer with the neural materials)")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in SUBCOMMANDS and not argv[0].startswith("-"):
        argv = ["convert"] + argv  # `mtlx2neural ASSET ...` is the conversion
    args = _parser().parse_args(argv)
    try:
        if args.command == "inspect":
            from .inspect import format_report, inspect_asset

            report = inspect_asset(args.asset, args.material, args.allow_missing_textures)
            print(json.dumps(report, indent=2) if args.json else format_report(report))
            return 0
        if args.command == "render":
            return _render(args)
        return _convert(args)
    except Mtlx2NeuralError as exc:
        print(f"mtlx2neural: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mtlx2neural: interrupted", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
