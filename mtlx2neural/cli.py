"""Command line: a thin shell over the library API.

    mtlx2neural ASSET [-o OUT] [--preset fast|standard|balanced|paper] [--decoder 2x16|2x32|3x64 | --max-error F]
                      [--max-texels N] [--texel-density D] [--workers N|ray|ray://HOST:PORT] [--force] ...
    mtlx2neural inspect ASSET [--material M] [--json] [--preset P] [--max-texels N] [--texel-density D]
    mtlx2neural render ASSET [--material M] [--model reference|neural] [--checkpoint PATH]
                       [--geometry sphere|plane|teapot|FILE.obj] [--env sky|FILE.hdr] [--mis own|none] -o OUT.exr
    mtlx2neural report OUT_neural.usda [--analytic-iterations N] [--texel U,V ...] [--train-sizes] [-o REPORT_DIR]

Exit codes: 0 ok, 1 failure, 2 bad input (the message names the file, prim or
node and what to do). A missed ``--max-error`` budget is not a failure: exit 0, with
a warning line per material and ``budget_met: false`` in its summary.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

from mtlx2neural.errors import Mtlx2NeuralError
from mtlx2neural.train.config import PRESETS

SUBCOMMANDS = ("inspect", "convert", "render", "report")
ASSET_SUFFIXES = (".mtlx", ".usd", ".usda", ".usdc", ".usdz")


def _looks_like_asset(word: str) -> bool:
    """``mtlx2neural WORD``: an asset (an existing path, or one with an asset suffix), not a mistyped command."""
    return word.lower().endswith(ASSET_SUFFIXES) or os.path.exists(word)


MAX_TEXELS_HELP = ("cap on the latent grid's longer side, in texels (default: the preset's: fast and standard 256, "
                   "balanced 1024, paper none; 0: no cap, the textures' own grid); a cap below the textures' "
                   "grid prefilters their finer detail, with a warning")


TEXEL_DENSITY_HELP = ("latent texels per metre of surface (e.g. 512 = 5.12 texels/cm): each material's grid "
                      "is scaled down to what its bound meshes' UVs need at this density (never up; "
                      "--max-texels still caps it), with a warning when that loses texture detail; "
                      "USD input only")


def _density(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a texel density (a positive number of latent texels "
                                         f"per metre, e.g. 512)")
    return value


def _texels(text: str) -> int:
    n = int(text) if text.strip().isdigit() else -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a texel count (a whole number; 0: no cap)")
    return n


def _budget(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not an HDR FLIP budget (a positive number, e.g. 0.1)")
    return value


def _workers(text: str):
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.pipeline.jobs import parse_workers

    try:
        return parse_workers(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _config(args):
    """The TrainConfig of ``args`` (preset, overrides, --max-texels)."""
    import dataclasses

    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.train.config import preset

    cfg = preset(args.preset, **{k: getattr(args, k, None) for k in ("decoder", "iterations", "batch", "frames",
                                                                     "seed")})
    if args.max_texels is not None:
        cfg = dataclasses.replace(cfg, max_resolution=args.max_texels or None)
    return cfg


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mtlx2neural", description="Bake MaterialX materials into neural materials.")
    sub = p.add_subparsers(dest="command", required=True)
    ins = sub.add_parser("inspect", help="list materials, bound prims, kept/pruned lobes, spatial inputs, textures")
    ins.add_argument("asset", help=".mtlx file or USD stage (.usda/.usdc/.usd)")
    ins.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    ins.add_argument("--json", action="store_true", help="print JSON instead of text")
    ins.add_argument("--allow-missing-textures", action="store_true",
                     help="use an image node's declared default when its file is missing")
    ins.add_argument("--preset", default="fast", choices=list(PRESETS),
                     help="settings the latent grid and the source hashes are shown for (default: fast)")
    ins.add_argument("--max-texels", type=_texels, metavar="N", help=MAX_TEXELS_HELP)
    ins.add_argument("--texel-density", type=_density, metavar="D", help=TEXEL_DENSITY_HELP)
    conv = sub.add_parser("convert", help="train a neural material for every selected material (default command)")
    conv.add_argument("asset", help=".mtlx file or USD stage")
    conv.add_argument("-o", "--output", help="output folder (default: ASSET_neural next to the input; the USD "
                                             "layer is written beside it as <folder>.usda), or the layer's path "
                                             "(OUT.usda, .usd or .usdc; the folder is then OUT). Never the input, "
                                             "a file it reads, or a file mtlx2neural did not write")
    conv.add_argument("--preset", default="fast", choices=list(PRESETS),
                      help="training settings: fast (minutes per material on a CPU: previews), standard (8x fast's "
                           "steps: the CPU's quality setting), balanced (a GPU), paper (the paper's 300k "
                           "steps; a GPU); default: fast")
    conv.add_argument("--decoder", choices=["2x16", "2x32", "3x64"],
                      help="force this decoder size for every material (default: the preset's; "
                           "conflicts with --max-error)")
    conv.add_argument("--max-error", type=_budget, metavar="F",
                      help="HDR FLIP budget (the summary's flip_mean): per material, train the smallest decoder "
                           "of 2x16, 2x32, 3x64 that meets it; when even 3x64 misses, keep the best and warn")
    conv.add_argument("--max-texels", type=_texels, metavar="N", help=MAX_TEXELS_HELP)
    conv.add_argument("--texel-density", type=_density, metavar="D", help=TEXEL_DENSITY_HELP)
    conv.add_argument("--workers", type=_workers, metavar="N|ray|ray://HOST:PORT",
                      help="train materials in parallel: N local processes (1: in this process, with progress "
                           "bars; default: one per material up to the CPU count, or per GPU), 'ray' (a local "
                           "Ray cluster, or $RAY_ADDRESS) or 'ray://HOST:PORT' (needs mtlx2neural[ray])")
    conv.add_argument("--iterations", type=int, metavar="N",
                      help="training steps (overrides the preset; 0 needs --allow-untrained)")
    conv.add_argument("--allow-untrained", action="store_true",
                      help="accept --iterations 0: export the untrained network (for pipeline tests)")
    conv.add_argument("--batch", type=int, metavar="N", help="samples per batch (overrides the preset)")
    conv.add_argument("--frames", type=int, metavar="N", help="learned shading frames (default 2; 0: none)")
    conv.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    conv.add_argument("--device", default="auto", help="cpu, cuda or auto (CUDA when present)")
    conv.add_argument("--seed", type=int, metavar="N", help="seed of the initial weights and training data")
    conv.add_argument("--resume", action="store_true", help="continue from the checkpoints in the output folder")
    conv.add_argument("--force", action="store_true",
                      help="retrain every material, even one unchanged since the last run (same source hash)")
    conv.add_argument("--allow-missing-textures", action="store_true",
                      help="use an image node's declared default when its file is missing")
    conv.add_argument("--quiet", action="store_true", help="no progress bars or per-material progress lines")
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
    ren.add_argument("--mis", default="own", choices=["own", "none"],
                     help="own (default): also one sample of the model's own BSDF sampler per pass, combined "
                          "by MIS; none: light samples only, every random number shared between models")
    ren.add_argument("--azimuth", type=float, default=30.0, help="degrees; 0 looks from +z, 90 from +x")
    ren.add_argument("--elevation", type=float, default=20.0, help="degrees above the horizon")
    ren.add_argument("--distance", type=float, default=4.0, help="camera distance in bounding-sphere radii")
    ren.add_argument("--fov", type=float, default=30.0, help="vertical field of view, degrees")
    ren.add_argument("--seed", type=int, default=0)
    ren.add_argument("--allow-missing-textures", action="store_true")
    rep = sub.add_parser("report", help="HTML report of a neural layer: renders, FLIP, analytic baseline, "
                                        "error versus cost, polar plots, training curves, latents, memory")
    rep.add_argument("layer", help="the neural USD layer that `mtlx2neural ASSET` wrote (ASSET_neural.usda)")
    rep.add_argument("-o", "--output", help="report folder (default: <layer stem>_report beside the layer)")
    rep.add_argument("--analytic-iterations", type=int, default=300, metavar="N",
                     help="Adam steps of the analytic (Lambert + GGX) baseline fit (default 300)")
    rep.add_argument("--res", type=int, default=96, help="render width and height in pixels (default 96)")
    rep.add_argument("--spp", type=int, default=8, help="samples per pixel of the renders (default 8)")
    rep.add_argument("--material", action="append", help="only this material (prim path or name; repeatable)")
    rep.add_argument("--texel", action="append", type=_uv, metavar="U,V",
                     help="texture coordinate of the polar plots (repeatable; default 0.5,0.5)")
    rep.add_argument("--train-sizes", action="store_true",
                     help="train the decoder sizes (2x16, 2x32, 3x64) the conversion did not, with its settings, "
                          "so that error versus cost shows every size (minutes per size)")
    return p


def _uv(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        u, v = (float(x) for x in parts)
    except ValueError:
        u = v = float("nan")
    if not (math.isfinite(u) and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} is not a texture coordinate: give U,V, e.g. 0.25,0.75")
    return u, v


def _report(args) -> int:
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.report.html_report import write_report

    r = write_report(args.layer, args.output, args.analytic_iterations, args.res, args.spp,
                     materials=args.material, texels_at=args.texel, train_sizes=args.train_sizes)
    for m in r["materials"]:
        print(f"{m['material']}: HDR FLIP neural {m['flip']['neural']:.4f}, analytic {m['flip']['analytic']:.4f}")
    print(f"wrote {r['html']}")
    return 0


def _render(args) -> int:
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.report.views import render_asset

    s = render_asset(args.asset, args.output, args.material, args.model, args.checkpoint, args.geometry,
                     args.env, args.res, args.spp, args.azimuth, args.elevation, args.distance, args.fov,
                     args.seed, args.allow_missing_textures, args.mis)
    print(f"{s['material']} ({s['model']}): {s['geometry']} under {s['env']} (MIS: {s['mis']}), {s['res']}x{s['res']}, "
          f"{s['spp']} spp in {s['seconds']} s; wrote {s['exr']} and {s['png']}")
    return 0


def _convert(args) -> int:
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.errors import InputError
    from mtlx2neural.pipeline.convert import convert_asset
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.train.trainer import TrainingInterrupted

    if args.decoder and args.max_error is not None:
        raise InputError(f"--decoder {args.decoder} and --max-error {args.max_error} conflict: --decoder forces "
                         f"one size, --max-error picks the smallest of 2x16, 2x32, 3x64 that meets the budget. "
                         f"Give one of them.")
    cfg = _config(args)
    try:
        summaries = convert_asset(args.asset, cfg, args.output, args.material, args.device, args.resume,
                                  not args.quiet, args.allow_missing_textures, force=args.force,
                                  preset=args.preset, workers=args.workers, max_error=args.max_error,
                                  texel_density=args.texel_density, allow_untrained=args.allow_untrained)
    except TrainingInterrupted as exc:
        print(f"mtlx2neural: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # writing failed after the up-front checks (disk full...); nothing partial was left
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"mtlx2neural: error: cannot write the output{where} ({exc.strerror or exc}); the previous export, "
              f"if any, is unchanged", file=sys.stderr)
        return 1
    out = summaries.folder
    for s in summaries:
        if s.get("shared_with"):
            how = f"identical to {s['shared_with']} (same graph, textures and settings): trained once, shared"
        elif s["cached"]:
            how = "reused (unchanged; --force retrains)"
        else:
            how = f"{s['steps']} steps in {s['seconds']} s"
        print(f"{s['material']}: {how}, decoder {s.get('decoder', s['config']['decoder'])}, held-out log-L1 "
              f"{s['held_out_log_l1']:.4f}, HDR FLIP {s['flip_mean']:.4f} (views {s['flip_per_view']})")
        budget = s.get("budget")
        if budget:
            tried = ", ".join(f"{k} {v:.4f}" for k, v in budget["flip_by_decoder"].items())
            print(f"  budget HDR FLIP <= {budget['max_error']}: {'met' if budget['met'] else 'NOT met'} "
                  f"(tried {tried})")
        for w in s.get("warnings", []):
            print(f"  warning: {w}")
        for n in s.get("latent", {}).get("notes", []):
            print(f"  note: {n}")
        notes = s.get("export_notes", [])
        for note in notes[:3]:
            print(f"  fp16: {note}")
        if len(notes) > 3:
            print(f"  fp16: ... and {len(notes) - 3} more (see neural/weights.json and export.json)")
    for k in getattr(summaries, "skipped", []):
        print(f"{k['material']}: skipped ({k['reason']})")
    print(f"wrote {out} (checkpoints, training curves, summaries, latent EXRs, weights)")
    if summaries:
        kept = getattr(summaries, "kept", [])
        also = f"; kept from earlier runs: {', '.join(kept)}" if kept else ""
        print(f"wrote {summaries[0]['usd']} (USD layer with the neural materials{also})")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in SUBCOMMANDS and not argv[0].startswith("-"):
        if not _looks_like_asset(argv[0]):
            print(f"mtlx2neural: error: unknown command '{argv[0]}': give one of {', '.join(SUBCOMMANDS)}, or an "
                  f"asset to convert (a path ending in {', '.join(ASSET_SUFFIXES)})", file=sys.stderr)
            return 2
        argv = ["convert"] + argv  # `mtlx2neural ASSET ...` is the conversion
    args = _parser().parse_args(argv)
    try:
        if args.command == "inspect":
            # Local: --help and option errors answer without importing torch.
            from mtlx2neural.pipeline.inspection import format_report, inspect_asset

            report = inspect_asset(args.asset, args.material, args.allow_missing_textures, _config(args),
                                   args.texel_density)
            print(json.dumps(report, indent=2) if args.json else format_report(report))
            return 0
        if args.command == "render":
            return _render(args)
        if args.command == "report":
            return _report(args)
        return _convert(args)
    except Mtlx2NeuralError as exc:
        print(f"mtlx2neural: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mtlx2neural: interrupted", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
