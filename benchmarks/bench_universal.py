"""The universal path against each material's own training: time per material and HDR FLIP.

Run:  python benchmarks/bench_universal.py ASSET [--material M ...] [--preset fast] [--steps N] [--json F]

For each material (all of ``ASSET``'s by default) it runs the project's own command three times, one
material at a time (``--material M --workers 1 --force``), each into its own folder:

- ``own``: ``--encoder material``, the material's own training (the preset's steps);
- ``universal``: ``--encoder universal --universal-tune networks``;
- ``universal-latents``: ``--encoder universal --universal-tune latents``.

It prints a markdown table: per material and path, the command's wall time (compiling, training, measuring,
exporting), the record's ``seconds`` (the material's own conversion: stack, training, measures), its
``train_seconds``, ``flip_mean`` (three directional sphere views and one under the sky) and the lowest
energy ratio. A material the universal path does not cover shows its reason. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mtlx2neural.universal.choice import STEPS

PATHS = {"own": ["--encoder", "material"],
         "universal": ["--encoder", "universal", "--universal-tune", "networks"],
         "universal-latents": ["--encoder", "universal", "--universal-tune", "latents"]}


def materials_of(asset: Path) -> list[str]:
    out = subprocess.run([sys.executable, "-m", "mtlx2neural.cli", "inspect", str(asset), "--json"],
                         capture_output=True, text=True, check=True).stdout
    return [m["material"] for m in json.loads(out)["materials"]]


def convert(asset: Path, material: str, out: Path, path: str, preset: str, steps: int) -> dict:
    cmd = [sys.executable, "-m", "mtlx2neural.cli", str(asset), "-o", str(out), "--material", material,
           "--preset", preset, "--workers", "1", "--force", "--quiet", "--universal-steps", str(steps), *PATHS[path]]
    t = time.time()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t
    if proc.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    (record,) = [json.loads(p.read_text()) for p in out.glob("*/summary.json")]
    enc = record.get("encoder") or {}
    return {"material": material, "path": path, "wall": round(wall, 1), "seconds": record["seconds"],
            "train_seconds": record["train_seconds"], "flip_mean": record["flip_mean"],
            "energy_min": round(record["energy"]["min_ratio"], 3) if record.get("energy") else None,
            "took": enc.get("path", "material"), "notes": record.get("notes", [])}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("asset", type=Path)
    p.add_argument("--material", action="append", help="a material to measure (repeatable; default: all)")
    p.add_argument("--preset", default="fast")
    p.add_argument("--steps", type=int, default=STEPS, help="--universal-steps (default: %(default)s)")
    p.add_argument("--paths", default=",".join(PATHS), help="comma-separated subset of " + ", ".join(PATHS))
    p.add_argument("--json", type=Path, help="also write the rows here")
    a = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_universal_") as tmp:
        for i, m in enumerate(a.material or materials_of(a.asset)):
            for path in a.paths.split(","):
                rows.append(convert(a.asset, m, Path(tmp) / f"{i}_{path}", path, a.preset, a.steps))
                print(json.dumps(rows[-1]), flush=True)
    print("\n| material | path | wall s | material s (training) | HDR FLIP | energy min |\n|---|---|---|---|---|---|")
    for r in rows:
        took = r["path"] if r["took"] == "universal" or r["path"] == "own" else f"{r['path']} (took its own)"
        print(f"| {r['material']} | {took} | {r['wall']} | {r['seconds']} ({r['train_seconds']}) | {r['flip_mean']} "
              f"| {r['energy_min']} |")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
