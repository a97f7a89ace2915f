"""The ``mtlx2neural`` argument parser, assembled from the command modules (each adds its own
subcommand), and the test that tells an asset from a mistyped command."""

from __future__ import annotations

import argparse
import os

from mtlx2neural.commands import bench, convert, inspection, render, report

COMMANDS = {m.NAME: m for m in (inspection, convert, render, report, bench)}
"""Subcommand name -> its module (``add_parser(subparsers)``, ``run(args) -> exit code``)."""
ASSET_SUFFIXES = (".mtlx", ".usd", ".usda", ".usdc", ".usdz", ".binary")


def looks_like_asset(word: str) -> bool:
    """``mtlx2neural WORD``: an asset (an existing path, or one with an asset suffix), not a mistyped command."""
    return word.lower().endswith(ASSET_SUFFIXES) or os.path.exists(word)


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser and each subcommand's, by name."""
    p = argparse.ArgumentParser(prog="mtlx2neural", description="Bake MaterialX materials into neural materials. "
                                "`mtlx2neural ASSET ...` is `mtlx2neural convert ASSET ...`.")
    sub = p.add_subparsers(dest="command", required=True)
    return p, {name: module.add_parser(sub) for name, module in COMMANDS.items()}


def command_parsers() -> dict[str, tuple[str, argparse.ArgumentParser]]:
    """Each subcommand's usage line and parser, the conversion first (docs/cli.md's option tables)."""
    _, parsers = build_parser()
    order = ["convert"] + [name for name in COMMANDS if name != "convert"]
    return {name: (COMMANDS[name].USAGE, parsers[name]) for name in order}
