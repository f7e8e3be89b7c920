#!/usr/bin/env bash
# The GPU run on a bare, offline GPU machine whose python3 has torch with CUDA, in the repository root:
#   bash eval/bench/gpu.sh BUNDLE OUT [run options]
# BUNDLE comes from `python -m eval.bench.gpu prepare BUNDLE` on a machine with the project installed. Installs the
# bundle's wheels into a private folder, builds abcgs's portable C++ kernels in place (the cuda tests compare gsplat's
# CUDA kernels with them) while gsplat's CUDA extension builds, then runs `python -m eval.bench.gpu run`.
set -euo pipefail
bundle=$1 out=$2
shift 2
mkdir -p "$out"
site=$(mktemp -d)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" "$bundle"/wheels/*.whl
export PYTHONPATH="$site:$PWD" PYTHONUNBUFFERED=1 HF_HUB_OFFLINE=1
export TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-$(python3 -c 'import torch; print("%d.%d" % torch.cuda.get_device_capability())')}"
export MAX_JOBS="${MAX_JOBS:-$(nproc)}"
start=$(date +%s)
ABCGS_KERNEL_VARIANTS=portable python3 setup.py -q build_ext --inplace >"$out/kernels_build.log" 2>&1 &
kernels=$!
export_ext=()
if [ -f "$bundle/gsplat_cuda.so.gz" ]; then
  # an earlier run's build (its --export-ext pieces, joined and gzipped), installed where gsplat looks first
  # (`from gsplat import csrc`), so that every process here uses it: this one and the pytest it starts
  gunzip -c "$bundle/gsplat_cuda.so.gz" >"$site/gsplat_cuda$(python3 -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')"
  printf 'import sys\n\nimport gsplat_cuda\n\nsys.modules[__name__] = gsplat_cuda\n' >"$site/gsplat/csrc.py"
else
  export_ext=(--export-ext "$out/ext")
  python3 -c 'from gsplat.cuda._backend import _C; assert _C is not None' 2>&1 | tail -40  # gsplat's JIT build
fi
wait "$kernels" || { echo "abcgs kernels did not build:"; tail -20 "$out/kernels_build.log"; }
echo "builds: $(( $(date +%s) - start )) s"
python3 -m eval.bench.gpu run --bundle "$bundle" --device cuda --json "$out/gpu.json" "${export_ext[@]}" "$@"
