"""The subcommands of ``mtlx2neural`` (:mod:`mtlx2neural.cli`), one module each: ``convert``,
``inspection`` (``inspect``), ``render``, ``report`` and ``bench``.

Each is a thin layer: it adds its arguments to the parser (generated from the options dataclass
of the library function it calls, :mod:`.options_cli`), builds that dataclass from argparse's
namespace, calls the library and prints the summary lines. :mod:`.parser` assembles them.
"""
