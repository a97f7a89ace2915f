#!/bin/bash
# Reproduce the prototype end to end (CPU only; ~30 s on 2 shared cores).
set -e
cd "$(dirname "$0")"
PY=/work/main/.venv/bin/python
SLANGC=/work/main/.venv/lib/python3.11/site-packages/slangtorch/bin/slangc
XR='xvfb-run -a -s "-screen 0 1024x768x24"'
mkdir -p out
$PY make_assets.py
$PY gen.py                                   # validate + generate GLSL (FIS/prefilter) + Slang
$PY try_slang_fallback.py                    # genslang using only the genglsl implementation
eval $XR $PY render.py reference_material.mtlx M_reference out/ref.png
eval $XR $PY render.py neural_material.mtlx M_neural out/neural_env0.png --env-mode 0
eval $XR $PY render.py neural_material.mtlx M_neural out/neural_env1.png --env-mode 1 --env-samples 64
eval $XR $PY render.py reference_material.mtlx M_reference out/ref_nodirect.png --no-direct
eval $XR $PY render.py neural_material.mtlx M_neural out/neural_env1_nodirect.png --no-direct --env-mode 1
eval $XR $PY render.py neural_material.mtlx M_neural out/neural_checker_lod4.png --explicit-mix 1 --lod 4
$PY compare.py
for s in "pixel fragmentMain fragment frag" "vertex vertexMain vertex vert"; do
  set -- $s
  $SLANGC out/M_neural_slang_fis_$1.slang -entry $2 -stage $3 -target spirv -emit-spirv-directly -O0 \
      -o out/M_neural_slang_$1.spv 2>/dev/null && echo "slangc spirv $1: ok"
  $SLANGC out/M_neural_slang_fis_$1.slang -entry $2 -stage $3 -target glsl -o out/M_neural_slang_$1.vk.glsl 2>/dev/null
  glslangValidator -V -S $4 out/M_neural_slang_$1.vk.glsl -o out/M_neural_slang_$1.vk.spv >/dev/null \
      && spirv-val --target-env vulkan1.1 out/M_neural_slang_$1.vk.spv && echo "slangc glsl -> glslang -> spirv-val $1: ok"
done
