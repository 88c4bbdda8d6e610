#!/usr/bin/env bash
# The GPU checks of the open issues, in one call on a machine with one NVIDIA GPU and JAX with
# CUDA installed: the demo, the box kernel at 1e5-1e7 pairs, the peers' box rows (MJX on the
# GPU), the distance benchmark and the peers' distance rows (MuJoCo C's
# mj_geomDistance on the host), and the fast test subset. Each step has its
# own time limit, so one that fails or runs long does not stop the others.
#
# Usage, from the repository root:  OUT=results-dir bash benchmarks/gpu.sh TAG [STEP ...]
# STEP: demo, kernels, peers, distance, peers-distance, tests (default: all, in that order).
# Writes TAG-named result files (.json, .md, .png) and a test report into $OUT/results.tgz.
# MuJoCo and MJX are optional: without them peers.py skips their rows.
set -u
tag="${1:-gpu}"
shift
steps=" ${*:-demo kernels peers distance peers-distance tests} "
out="${OUT:-/tmp/jaxsat-gpu}"
results="$out/results"
mkdir -p "$results"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
# Several processes share the GPU (the test workers): allocate on demand, not 75% each.
export XLA_PYTHON_CLIENT_PREALLOCATE=false

step() {
    local limit=$1
    shift
    echo "== $(date -u +%T) [limit ${limit}s] $*"
    timeout "$limit" "$@"
    local status=$?
    echo "== $(date -u +%T) exit status $status"
}

nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import jax, numpy; print('jax', jax.__version__, 'numpy', numpy.__version__, jax.devices())"

[[ $steps == *" demo "* ]] && step 60 python3 -m jaxsat demo --output "$results/demo-$tag.png"
[[ $steps == *" kernels "* ]] && step 120 python3 benchmarks/kernels.py --cases 3d-boxes --sizes 100000 1000000 10000000 \
    --output "$results/kernels-boxes-$tag"
# MuJoCo C runs on the host in a Python loop; its rows are in results/peers-boxes-cpu-2core.
[[ $steps == *" peers "* ]] && step 120 python3 benchmarks/peers.py --cases 3d-boxes \
    --methods jaxsat jaxsat-chunked mjx \
    --sizes 100000 1000000 10000000 --max-call-seconds 5 --repeats 3 --output "$results/peers-boxes-$tag"
[[ $steps == *" distance "* ]] && step 330 python3 benchmarks/distance.py --sizes 100000 1000000 --output "$results/distance-$tag"
[[ $steps == *" peers-distance "* ]] && step 150 python3 benchmarks/peers.py --cases 3d-boxes 3d-hulls \
    --methods jaxsat-distance mujoco-distance --sizes 10000 100000 1000000 --max-call-seconds 5 \
    --repeats 3 --output "$results/peers-distance-$tag"
[[ $steps == *" tests "* ]] && step 150 python3 -m pytest -m "not slow" -n 8 -p no:cacheprovider -q -ra \
    --junitxml="$results/tests-fast-$tag.xml"

tar czf "$out/results.tgz" -C "$out" results
ls -la "$results"
