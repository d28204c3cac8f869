# The preamble of the one-script GPU measurements (gpu_novelty.sh, gpu_skill_methods.sh,
# gpu_seed_benchmark.sh), sourced with the script's arguments: makes OUT_DIR ($1) and sets `out`
# (its absolute path), `here` (benchmarks/), `py` ($PY or python3), `log` (OUT_DIR/log.txt), and
# exports JAX_PLATFORMS ($PLATFORM or cuda) and PYTHONUNBUFFERED.
out=${1:?usage: $(basename "$0") OUT_DIR}
mkdir -p "$out"
out=$(cd "$out" && pwd)
here=$(cd "$(dirname "$0")" && pwd)
py=${PY:-python3}
export PYTHONUNBUFFERED=1 JAX_PLATFORMS=${PLATFORM:-cuda}
log=$out/log.txt
