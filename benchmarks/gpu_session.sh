#!/usr/bin/env bash
# Issue 31's checks on a CUDA machine, most wanted first, in one call of the
# device tool (about 8 minutes on an H200; each step capped, a failed step
# does not stop the next):
#
#   bash benchmarks/gpu_session.sh            # logs and CSVs under $OUT (or outputs/gpu)
#
# The device image has Python 3.12 without Taichi: carry the wheels (56 MB
# with the 4.7 MB tree, under the 64 MiB a call takes), made here once with
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#     --implementation cp --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
#     -d .whl taichi==1.7.4 dill meshio
# and start the device command with (carry: [".whl"])
#   python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir \
#     --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD && \
#   bash benchmarks/gpu_session.sh
#
# 1. which several-column BiCGSTAB kernel faults (benchmarks/bicg_columns_probe.py);
# 2. the 1M window, work arrays on the device and in numpy alternating
#    (target: <= 1 s warm; benchmarks/natural_scale.py --resident both);
# 3. every case on cpu and cuda with the largest difference (benchmarks/arch.py,
#    project included);
# 4. the droplet at 160k particles (target >= 3e6 particle-steps/s);
# 5. the device path's tests and the joint solve of two columns on CUDA
#    ($TAICHI_HH_JOINT_COLUMNS=1, to be enabled where the probe's bicg_step runs);
# 6. where the image has a Vulkan driver for the GPU, the same cases on Vulkan
#    (never yet run on a GPU's Vulkan; its work arrays on the device since the
#    twelfth session).  The caps add up to more than a call's 600 s: the steps
#    are in order of need, and a call cut short still returns what $OUT holds.
set -u
cd "$(dirname "$0")/.."
out="${OUT:-outputs/gpu}"
mkdir -p "$out"
export TAICHI_HH_ARCH=cuda
python=$(command -v python3 || command -v python)
step() {
  local name=$1 limit=$2
  shift 2
  echo "== $name ($(date +%T), at most ${limit} s): $*"
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  echo "   rc $? ; last lines:"
  tail -n 15 "$out/$name.log"
}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > "$out/gpu.txt" 2>&1
cat "$out/gpu.txt"
step probe 150 $python benchmarks/bicg_columns_probe.py --arch cuda --out-dir "$out"
step natural_1m 150 $python benchmarks/natural_scale.py --sizes 1000000 --repeats 5 \
  --resident both --kernels --out-dir "$out"
step arch 120 $python benchmarks/arch.py --arches cpu,cuda --sizes 10000 --steps 3 --repeats 2 \
  --out-dir "$out"
step droplet_160k 90 $python benchmarks/flow_profile.py --particles 160000 --warmup 3 --steps 8 \
  --arch cuda --out-dir "$out"
step tests 120 env TAICHI_HH_JOINT_COLUMNS=1 $python -m pytest -q -p no:cacheprovider -x \
  tests/test_arch.py tests/test_resident.py tests/test_lanes.py tests/test_columns.py
step arch_vulkan 90 $python benchmarks/arch.py --arches cpu,vulkan --sizes 10000 --steps 3 \
  --repeats 1 --out-dir "$out/vulkan"
