#!/usr/bin/env bash
# Every GPU measurement qdrl records, as one script with a time limit per step and
# one for the whole (a GPU machine is lent for minutes, not hours):
#
#   bash benchmarks/gpu_session.sh OUT_DIR
#
# 0. a policy scores the same alone and in its batch (benchmarks/batch_reproduce.py);
# 1. MAP-Elites on the 100-DoF arm against QDax 0.5.0, CVT 1024, batch 1024, 2 seeds
#    (fresh processes, alternating) with both sides' compiled GPU HLO per step;
# 2. the kernels each side's timed program launches (benchmarks/kernel_trace.py);
# 3. the same pair at batch 16384, and on the 100x100 grid at batch 1024 (1 seed);
# 4. the CMA-MAE 100-D spec (agents/cma_mae_lp_sphere.toml) through `qdrl run`;
# 5. `qdrl bench map_elites`;
# 6. MAP-Elites on halfcheetah_uni against QDax (benchmarks/compare_qdax_brax.py).
#
# Environment: PY (python with qdrl importable; default python3), QDAX_PY (python
# with qdax==0.5.0; default PY), PLATFORM (JAX_PLATFORMS of every run: cuda, or cpu
# to try the script's mechanics), BUDGET (seconds for the whole script; default
# 430), QUICK=1 (tiny sizes, to try the mechanics). Each step's output goes to
# OUT_DIR/log.txt; results to OUT_DIR/*.json and OUT_DIR/cma_mae.tgz (8 files).
set -u
out=${1:?usage: gpu_session.sh OUT_DIR}
mkdir -p "$out"
out=$(cd "$out" && pwd)
here=$(cd "$(dirname "$0")" && pwd)
py=${PY:-python3}
qpy=${QDAX_PY:-$py}
platform=${PLATFORM:-cuda}
deadline=$((SECONDS + ${BUDGET:-430}))
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
log=$out/log.txt
if [[ ${QUICK:-0} == 1 ]]; then
    sizes=(--batch 64 --iterations 10); big=(--batch 256 --iterations 10); steps=10; seeds=1
    cma_set=(--set qd.num_iterations=40 --set qd.log_every=20)
else
    sizes=(--batch 1024 --iterations 200); big=(--batch 16384 --iterations 200); steps=200; seeds=2
    cma_set=()
fi

# step NAME LIMIT CMD...: run CMD in its own process group for at most LIMIT seconds
# (less when the script's budget is nearer), log its output, record its status.
step() {
    local name=$1 limit=$2
    shift 2
    local left=$((deadline - SECONDS))
    if ((left < 15)); then
        echo "{\"step\": \"$name\", \"skipped\": \"budget spent\"}" | tee -a "$log"
        return
    fi
    ((limit > left)) && limit=$left
    echo "=== $name (limit ${limit} s): $*" >>"$log"
    local t0=$SECONDS
    timeout -k 5 "$limit" "$@" >>"$log" 2>&1
    local rc=$?
    echo "{\"step\": \"$name\", \"rc\": $rc, \"s\": $((SECONDS - t0))}" | tee -a "$log"
}

export PYTHONUNBUFFERED=1 JAX_PLATFORMS=$platform
unset MUJOCO_GL
cd "$here/.." || exit 1
step devices 60 "$py" -c "import jax, qdrl; print(jax.__version__, jax.devices())"
step devices_qdax 60 "$qpy" -c "import jax, qdax; print(jax.__version__, jax.devices())"
nvidia-smi -L >>"$log" 2>&1
step batch_reproduce 90 "$py" benchmarks/batch_reproduce.py --policies 12 --eval-batch 8
step arm_pair_1024 150 "$py" benchmarks/compare_qdax_map_elites.py --platform "$platform" \
    --qdax-python "$qpy" --seeds "$seeds" --containers cvt1024 "${sizes[@]}" --out "$out/arm_pair_1024.json"
step kernels_qdrl 60 "$py" benchmarks/kernel_trace.py --out "$work/kernels_qdrl.json" --steps "$steps" -- \
    benchmarks/compare_qdax_map_elites.py --side qdrl --containers cvt1024 "${sizes[@]}"
step kernels_qdax 60 "$qpy" benchmarks/kernel_trace.py --out "$work/kernels_qdax.json" --steps "$steps" -- \
    benchmarks/qdax_map_elites_arm.py --container cvt --num-centroids 1024 "${sizes[@]}"
"$py" -c 'import json, sys; from pathlib import Path
w, o = Path(sys.argv[1]), Path(sys.argv[2])
d = {s: json.loads((w / f"kernels_{s}.json").read_text()) for s in ("qdrl", "qdax") if (w / f"kernels_{s}.json").exists()}
o.write_text(json.dumps(d, indent=1) + "\n")' "$work" "$out/kernels.json" 2>>"$log"
step arm_pair_16384 100 "$py" benchmarks/compare_qdax_map_elites.py --platform "$platform" \
    --qdax-python "$qpy" --seeds "$seeds" --containers cvt1024 --hlo-containers \
    "${big[@]}" --out "$out/arm_pair_16384.json"
step arm_pair_grid100 70 "$py" benchmarks/compare_qdax_map_elites.py --platform "$platform" \
    --qdax-python "$qpy" --seeds 1 --containers grid100 --hlo-containers \
    "${sizes[@]}" --out "$out/arm_pair_grid100.json"
step cma_mae 150 "$py" -m qdrl.cli run cma_mae_lp_sphere --out "$work/cma_mae" --overwrite "${cma_set[@]}"
tar czf "$out/cma_mae.tgz" -C "$work" --exclude checkpoints --exclude repertoire.npz cma_mae 2>>"$log"
if [[ ${QUICK:-0} == 1 ]]; then bench=(--quick); else bench=(); fi
step bench_map_elites 90 "$py" -m qdrl.cli bench map_elites "${bench[@]}" --out "$out/bench_map_elites.json"
step halfcheetah_pair 130 "$py" benchmarks/compare_qdax_brax.py --platform "$platform" --qdax-python "$qpy" \
    --seeds 1 --out "$out/halfcheetah_pair.json"
echo "{\"step\": \"end\", \"s\": $SECONDS}" | tee -a "$log"
