"""``mtlx2neural bench [NAMES...] [--list]``: run the benchmarks of a source checkout.

The benchmarks are the scripts in the repository's ``benchmarks/`` folder (``run_all.py`` lists
them, with their arguments); each writes its Markdown table to ``benchmarks/results/<name>.md``.
They are not part of the installed package: from a wheel, without the folder, the command says
to run it from a checkout (exit 2).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
from pathlib import Path

from mtlx2neural.errors import InputError

NAME = "bench"
USAGE = "mtlx2neural bench [NAME ...]"
HELP = "run the benchmarks of a source checkout (benchmarks/run_all.py); tables go to benchmarks/results/"


def benchmarks_folder() -> Path | None:
    """The ``benchmarks/`` folder of the source checkout this package runs from, else None (an
    installed wheel): the folder beside the package, with ``run_all.py``, in a folder that has
    ``pyproject.toml``."""
    root = Path(__file__).resolve().parents[2]
    folder = root / "benchmarks"
    return folder if (folder / "run_all.py").is_file() and (root / "pyproject.toml").is_file() else None


def benchmarks(folder: Path) -> dict[str, tuple[str, list[str], dict]]:
    """``run_all.BENCHMARKS`` of ``folder``: name -> (script, arguments, extra environment)."""
    spec = importlib.util.spec_from_file_location("mtlx2neural_benchmarks_run_all", folder / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return dict(module.BENCHMARKS)


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}. Benchmarks time things: "
                                                    f"run them on an otherwise idle machine (the full set "
                                                    f"takes about two hours on a 2-core CPU).")
    p.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run, in this order (default: all)")
    p.add_argument("--list", action="store_true", help="list the benchmarks and their commands; run nothing")
    return p


def run(args: argparse.Namespace) -> int:
    folder = benchmarks_folder()
    if folder is None:
        raise InputError("bench runs the benchmark scripts of a source checkout, and this mtlx2neural is "
                         f"installed without them (no benchmarks/run_all.py beside {Path(__file__).parents[1]}). "
                         "Run it from a checkout: git clone the repository, pip install -e . there, then "
                         "mtlx2neural bench")
    table = benchmarks(folder)
    unknown = [n for n in args.names if n not in table]
    if unknown:
        raise InputError(f"unknown benchmark {', '.join(map(repr, unknown))}: choose from {', '.join(table)} "
                         f"(mtlx2neural bench --list)")
    if args.list:
        for name, (script, argv, env) in table.items():
            if not args.names or name in args.names:
                settings = " ".join(f"{k}={v}" for k, v in env.items())
                print(f"{name:10s} {' '.join(filter(None, [settings, 'benchmarks/' + script, *argv]))}")
        return 0
    command = [sys.executable, str(folder / "run_all.py")] + (["--only", ",".join(args.names)] if args.names else [])
    return subprocess.run(command, cwd=folder.parent, check=False).returncode
