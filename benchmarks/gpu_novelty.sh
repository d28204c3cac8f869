#!/usr/bin/env bash
# The GPU timings of the search archives, as one script under 5 minutes:
#
#   bash benchmarks/gpu_novelty.sh OUT_DIR
#
# 1. Discount Model Search on the LP sphere (agents/dms_lp_sphere.toml: 15 CMA-ES emitters of 36,
#    100-D, the discount MLP trained every iteration) for 1,000 iterations;
# 2. Dominated Novelty Search on the LP sphere (agents/dns_lp_sphere.toml: a population of 1024,
#    540 iso-line offspring per iteration) for 1,000 iterations;
# 3. NSLC on the LP sphere (agents/nslc_lp_sphere.toml) for 1,000 iterations;
# 4. DNS on walker2d_uni (agents/dns_walker2d_uni.toml, QDax's example: 100 policies of 100 steps
#    per iteration) for at most 60 s of iterations (experiment.time_limit_s).
# Each run's summary (wall_s, compile_s, run_s, evaluations, QD score) is copied to
# OUT_DIR/<spec>.json; the CPU figures to set beside them are in docs/algorithms/novelty.md.
#
# Environment: PY (python with qdrl importable; default python3), PLATFORM (JAX_PLATFORMS:
# cuda, or cpu to try the mechanics), QUICK=1 (20 iterations each, to try the mechanics).
set -u
source "$(dirname "$0")/gpu_env.sh" "$@"
if [[ ${QUICK:-0} == 1 ]]; then iterations=20; limit=20; else iterations=1000; limit=60; fi
qdrl=("$py" -c "import sys; from qdrl.cli import main; sys.exit(main(sys.argv[1:]))")

run() {  # run SPEC SECONDS [--set KEY=VALUE ...]
    local spec=$1 seconds=$2
    shift 2
    echo "=== $spec" >>"$log"
    timeout -k 5 "$seconds" "${qdrl[@]}" run "$here/../agents/$spec.toml" --out "$out/$spec" \
        --set log.plots=false --set log.progress=false "$@" >>"$log" 2>&1
    echo "{\"step\": \"$spec\", \"rc\": $?}" | tee -a "$log"
    cp "$out/$spec/summary.json" "$out/$spec.json" 2>/dev/null
}

lp=(--set "qd.num_iterations=$iterations" --set "qd.log_every=$iterations")
run dms_lp_sphere 60 "${lp[@]}"
run dns_lp_sphere 45 "${lp[@]}"
run nslc_lp_sphere 60 "${lp[@]}"
run dns_walker2d_uni $((limit + 75)) --set "experiment.time_limit_s=$limit" --set qd.log_every=10
