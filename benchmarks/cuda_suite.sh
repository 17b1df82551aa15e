#!/usr/bin/env bash
# The GPU checks in one go, for a machine with CUDA (Vulkan too, where its loader is installed): the
# GPU-marked tests, the CUDA benchmarks and two demos on CUDA. Each stage has a time limit, so one that
# hangs does not take the others with it; logs and result pages go to OUT, packed into OUT/cuda_suite.tgz.
#
#   bash benchmarks/cuda_suite.sh OUT [STAGE ...]     (stages: tests particles demos cloth spheres breakdown;
#                                                      default all)
#
# Python is $PY (default python3); it needs taichi, and warp-lang for the cloth and spheres peers.
set -u
out=${1:?usage: cuda_suite.sh OUT [STAGE ...]}
shift
stages=${*:-tests particles demos cloth spheres breakdown}
py=${PY:-python3}
mkdir -p "$out"
export PYTHONUNBUFFERED=1

stage() { # name, seconds, command...
  local name=$1 limit=$2
  shift 2
  echo "== $name ($(date -u +%T))"
  timeout "$limit" "$@" >"$out/$name.log" 2>&1
  echo "rc=$? $name ($(date -u +%T))"
  tail -n 6 "$out/$name.log"
}

nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv >"$out/gpu.txt" 2>&1
cat "$out/gpu.txt"
for s in $stages; do
  case $s in
  tests) stage tests 240 "$py" -m pytest -q -m gpu -p no:cacheprovider tests/test_backends.py ;;
  particles) stage particles 240 "$py" benchmarks/particles.py --arch cuda --out "$out" ;;
  demos)
    for d in fountain cloth; do
      stage "demo_$d" 60 "$py" -m taichi_anim demo "$d" --arch cuda --frames 120 --no-export
    done
    ;;
  cloth) stage cloth 120 "$py" benchmarks/cloth_warp.py --arch cuda --out "$out" ;;
  spheres) stage spheres 150 "$py" benchmarks/spheres.py --arch cuda --out "$out" ;;
  breakdown) stage breakdown 180 "$py" benchmarks/step_breakdown.py --arch cuda --out "$out" ;;
  *) echo "unknown stage $s" ;;
  esac
done
tar -czf "$out/../cuda_suite.tgz" -C "$out" . && mv "$out/../cuda_suite.tgz" "$out/"
