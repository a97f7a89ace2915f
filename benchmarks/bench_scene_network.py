"""One shared network against one network per material, on a whole asset: wall time, HDR FLIP, weight
bytes and the number of distinct networks shipped.

Run:  python benchmarks/bench_scene_network.py ASSET [--preset fast] [--max-texels N] [--encoder universal]
                                                    [--out DIR] [--json F]
      python benchmarks/bench_scene_network.py ASSET --add MATERIAL [--preset fast] ...

Converts ``ASSET`` twice with the project's own command, ``--network material`` (the default worker
pool: one process per core) and ``--network scene`` (training in one process, measures in the pool), each
into its own folder with ``--force`` (``--encoder`` applies to the scene run), and prints a markdown
table: the conversion's wall time (the whole command:
compiling, training, measuring, exporting), mean and worst ``flip_mean`` (the three sphere views
against the reference), the shipped weight files' bytes (every material's ``weights.bin``) and how many
of them differ. Run it on an otherwise idle machine: the ratio of the two wall times is the figure.

``--add MATERIAL`` (a material prim's path) measures a material added to a converted scene instead: a
layer beside the output sublayers ``ASSET`` and unbinds the prims bound to MATERIAL; it is converted with
``--network scene``, then the unbinding is removed from the same layer and it is converted again (the
others reused, MATERIAL fitted into the kept network), then once more with ``--force`` (the whole group
trained together). The table gives each run's wall time and MATERIAL's HDR FLIP in the last two.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def convert(asset: Path, out: Path, network: str, preset: str, max_texels: int | None, force: bool = True,
            encoder: str = "material") -> dict:
    """Run one conversion; its wall time and the figures read back from the written records."""
    cmd = [sys.executable, "-m", "mtlx2neural.cli", str(asset), "-o", str(out), "--preset", preset,
           "--network", network, "--encoder", encoder, "--quiet", *(["--force"] if force else [])]
    if max_texels is not None:
        cmd += ["--max-texels", str(max_texels)]
    t = time.time()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.time() - t
    if proc.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    records = [json.loads(p.read_text()) for p in sorted(out.glob("*/summary.json"))]
    weights = sorted(out.glob("*/neural/weights.bin"))
    digests = {hashlib.sha256(p.read_bytes()).hexdigest() for p in weights}
    flips = [r["flip_mean"] for r in records]
    return {"network": network + (f" --encoder {encoder}" if encoder != "material" else ""), "seconds": round(seconds, 1), "materials": len(records),
            "flip_mean": round(sum(flips) / len(flips), 4), "flip_worst": round(max(flips), 4),
            "flip_by_material": {r["material"]: r["flip_mean"] for r in records},
            "weight_bytes": sum(p.stat().st_size for p in weights), "distinct_networks": len(digests),
            "shared_seconds": next((r["network"]["seconds"] for r in records if r.get("network")), None)}


def _unbind(layer: Path, asset: Path, material: str, unbind: bool) -> None:
    """Write ``layer``: ``asset`` as its sublayer, plus (``unbind``) empty bindings on the prims bound to
    ``material``."""
    from pxr import Sdf, Usd, UsdShade

    stage = Usd.Stage.Open(str(asset))
    bound = [p.GetPath() for p in stage.Traverse()
             if UsdShade.MaterialBindingAPI(p).GetDirectBinding().GetMaterialPath() == Sdf.Path(material)]
    if not bound:
        raise SystemExit(f"{asset}: no prim is bound to {material}")
    out = Sdf.Layer.FindOrOpen(str(layer)) or Sdf.Layer.CreateNew(str(layer))
    out.Clear()
    out.subLayerPaths.append(str(asset))
    if unbind:
        over = Usd.Stage.Open(out)
        for path in bound:
            over.OverridePrim(path).CreateRelationship("material:binding").SetTargets([])
    out.Save()


def added(asset: Path, material: str, base: Path, preset: str, max_texels: int | None) -> list[dict]:
    """The three conversions of ``--add`` (module docstring)."""
    base.mkdir(parents=True, exist_ok=True)
    layer, out = base / "asset.usda", base / "scene"
    _unbind(layer, asset, material, True)
    rows = [{**convert(layer, out, "scene", preset, max_texels), "run": f"without {material}"}]
    _unbind(layer, asset, material, False)
    rows.append({**convert(layer, out, "scene", preset, max_texels, force=False), "run": f"{material} added"})
    rows.append({**convert(layer, out, "scene", preset, max_texels), "run": "the whole group trained again"})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("asset", type=Path)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--max-texels", type=int, default=None, help="latent grid cap for both runs (default: the preset's)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the two conversions (default: a temporary one)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON here")
    ap.add_argument("--encoder", default="material", choices=("material", "universal"),
                    help="--encoder of the --network scene run (universal: the group starts from a shipped network)")
    ap.add_argument("--add", default=None, metavar="MATERIAL", help="measure adding this material to a converted scene")
    args = ap.parse_args()
    base = args.out or Path(tempfile.mkdtemp(prefix="bench_scene_network_"))
    if args.add:
        rows = added(args.asset.resolve(), args.add, base, args.preset, args.max_texels)
        print(f"{args.asset.name}, --network scene, --preset {args.preset}, adding {args.add}")
        print("| run | materials | wall s | HDR FLIP of the added material | mean HDR FLIP |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['run']} | {r['materials']} | {r['seconds']} | {r['flip_by_material'].get(args.add, '-')} | "
                  f"{r['flip_mean']} |")
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return 0
    rows = [convert(args.asset.resolve(), base / network, network, args.preset, args.max_texels,
                    encoder=args.encoder if network == "scene" else "material") for network in ("material", "scene")]
    print(f"{args.asset.name}, --preset {args.preset}" + (f", --max-texels {args.max_texels}" if args.max_texels else ""))
    print("| network | materials | wall s | mean HDR FLIP | worst | weight bytes | distinct networks |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['network']} | {r['materials']} | {r['seconds']} | {r['flip_mean']} | {r['flip_worst']} | "
              f"{r['weight_bytes']} | {r['distinct_networks']} |")
    print(f"time ratio material / scene: {rows[0]['seconds'] / rows[1]['seconds']:.2f}x; "
          f"mean FLIP ratio scene / material: {rows[1]['flip_mean'] / rows[0]['flip_mean']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
