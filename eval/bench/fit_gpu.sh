#!/usr/bin/env bash
# A fit of a reconstructed scene on a lent GPU machine (bare and offline), for the benchmarks that need a better fit
# than the CPU makes in minutes, e.g. the bonsai masks benchmark (docs/MASKS.md):
#   bash eval/bench/fit_gpu.sh BUNDLE WORK SCENE ITERATIONS OUT
# BUNDLE: `python -m eval.bench.gpu prepare BUNDLE` (its wheels/ and an earlier run's gsplat_cuda.so.gz); WORK/SCENE/
# colmap: the reconstruct stage's output (eval.bench.fit --work); every view is trained (--test-every 0). Writes
# OUT/SCENE_fit.json and OUT/point_cloud.ply.gz.part* (gzip, split to the device tool's 15 MiB per file).
set -euo pipefail
bundle=$1 work=$2 scene=$3 iterations=$4 out=$5
mkdir -p "$out" "$work/.scene/$scene"
site=$(mktemp -d)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" "$bundle"/wheels/*.whl
gunzip -c "$bundle/gsplat_cuda.so.gz" >"$site/gsplat_cuda$(python3 -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')"
printf 'import sys\n\nimport gsplat_cuda\n\nsys.modules[__name__] = gsplat_cuda\n' >"$site/gsplat/csrc.py"
export PYTHONPATH="$site:$PWD" PYTHONUNBUFFERED=1
start=$(date +%s)
python3 -m eval.bench.fit --scene "$work/.scene/$scene" --work "$work" --iterations "$iterations" \
  --eval-every $((iterations / 3)) --max-gaussians 300000 --reset-every 3000 --test-every 0 --device cuda \
  --json "$out/${scene}_fit.json" 2>&1 | tr '\r' '\n' | grep -v "it/s]$" | tail -20
echo "fit: $(( $(date +%s) - start )) s"
gzip -c "$work/$scene/gs/point_cloud.ply" | split -b 15M - "$out/point_cloud.ply.gz.part"
