"""Mitsuba 3 plugins and scenes: this project's materials inside a path tracer it did not write.

An optional component (``pip install "mtlx2neural[mitsuba]"``). Two BSDF plugins are registered with
Mitsuba by :func:`register_plugins`:

- ``mtlx_neural`` (:mod:`.neural_bsdf`): a converted material read from its exported layer's files
  (latent textures, FP16 weights), evaluated in Dr.Jit;
- ``mtlx_reference`` (:mod:`.reference_bsdf`): the compiled MaterialX reference BRDF.

:func:`load_mitsuba` imports Mitsuba, points Dr.Jit's LLVM backend at a libLLVM new enough for it and
selects the variant (:data:`VARIANT`). Dr.Jit loads libLLVM at run time; releases older than LLVM 16
fail on every render ("LLVM ERROR: Cannot select: ... fminimum"), so :func:`find_libllvm` prefers the
newest library present and ``DRJIT_LIBLLVM_PATH``, when set, wins. :func:`mitsuba_missing` says why the
component cannot run here (or None), for the CLI's error and the tests' skip reason.

Conventions shared with Mitsuba (each plugin's docstring maps them onto :mod:`mtlx2neural.contract`):
Mitsuba's ``si.wi`` is the direction towards the viewer in the local shading frame (z the shading
normal, x ``si.sh_frame.s``, the direction of dp/du), the contract's ``wi``; the ``wo`` argument of
``eval``/``pdf`` and the sampled ``bs.wo`` point towards the light, the contract's ``wo``; ``eval``
includes the cosine factor, as the contract's does.
"""

from __future__ import annotations

import glob
import os
import re

VARIANT = "llvm_ad_rgb"
"""The Mitsuba variant: Dr.Jit's LLVM (CPU) backend, RGB, with automatic differentiation (which
``dr.wrap`` to torch needs)."""

MIN_LLVM = 16
"""The oldest libLLVM major version Dr.Jit 1.5's LLVM backend renders with."""

INSTALL_HINT = ('pip install "mtlx2neural[mitsuba]" (mitsuba 3.9.1, drjit 1.5.0), and a libLLVM >= 16 '
                "(Debian/Ubuntu: apt-get install libllvm19) or DRJIT_LIBLLVM_PATH naming one")


def find_libllvm() -> str | None:
    """``DRJIT_LIBLLVM_PATH`` when set, else the newest ``libLLVM`` of major version >= :data:`MIN_LLVM`
    in the usual library folders, else None."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    found = []
    for folder in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
                   "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib"):
        for path in glob.glob(os.path.join(folder, "libLLVM*")):
            m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= MIN_LLVM:
                found.append((int(m.group(1)), path))
    return max(found)[1] if found else None


def mitsuba_missing() -> str | None:
    """Why Mitsuba cannot run here (a sentence naming what to install), or None when it can."""
    try:
        # Local: an optional dependency, imported only to see whether it is there.
        import mitsuba  # noqa: F401
    except ImportError:
        return f"Mitsuba 3 is not installed: {INSTALL_HINT}"
    if find_libllvm() is None:
        return f"no libLLVM >= {MIN_LLVM} for Dr.Jit's LLVM backend: {INSTALL_HINT}"
    return None


def load_mitsuba():
    """The ``mitsuba`` module with :data:`VARIANT` selected and both plugins registered; ImportError
    (naming what to install) when the component cannot run here."""
    reason = mitsuba_missing()
    if reason is not None:
        raise ImportError(reason)
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", find_libllvm())
    # Local: optional; DRJIT_LIBLLVM_PATH must be set before Dr.Jit first starts its LLVM backend.
    import mitsuba as mi

    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    register_plugins()
    return mi


_REGISTERED: set[str] = set()


def register_plugins() -> None:
    """Register ``mtlx_neural`` and ``mtlx_reference`` with Mitsuba (once per variant)."""
    # Local: optional dependency (Mitsuba), and the plugins' modules import it at module level.
    import mitsuba as mi

    if mi.variant() in _REGISTERED:
        return
    # Local: these modules subclass mi.BSDF, which exists only once a variant is set.
    from mtlx2neural.mitsuba.neural_bsdf import NeuralBSDF
    from mtlx2neural.mitsuba.reference_bsdf import ReferenceBSDF

    mi.register_bsdf("mtlx_neural", lambda props: NeuralBSDF(props))
    mi.register_bsdf("mtlx_reference", lambda props: ReferenceBSDF(props))
    _REGISTERED.add(mi.variant())
