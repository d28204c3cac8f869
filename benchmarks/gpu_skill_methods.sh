#!/usr/bin/env bash
# The GPU measurements of today's skill methods, as one script under 8 minutes:
#
#   bash benchmarks/gpu_skill_methods.sh OUT_DIR
#
# 1. QDAC on walker2d feet contact at the paper's settings (agents/qdac_walker2d_feet_contact.toml:
#    256 environments, one gradient step per environment step on batches of 256 + 256 relabelled,
#    1000-step episodes) for a fixed 180 s of training (experiment.time_limit_s), then its
#    env steps per second and distance to skill from the run's summary;
# 2. `qdrl bench skill_methods`: QDAC, UVFA, DOMiNO, SMERL on walker2d feet contact and METRA,
#    LSD, DIAYN on ant_omni, each beside SAC (16 envs x 16 updates, 256x256).
#
# Environment: PY (python with qdrl importable; default python3), PLATFORM (JAX_PLATFORMS:
# cuda, or cpu to try the mechanics), QUICK=1 (20 s of QDAC, the bench's quick sizes).
# Output: OUT_DIR/log.txt, OUT_DIR/qdac_summary.json, OUT_DIR/skill_methods.json.
set -u
source "$(dirname "$0")/gpu_env.sh" "$@"
if [[ ${QUICK:-0} == 1 ]]; then limit=20; quick=(--quick); else limit=180; quick=(); fi
qdrl=("$py" -c "import sys; from qdrl.cli import main; sys.exit(main(sys.argv[1:]))")

echo "=== qdac_walker2d_feet_contact for ${limit} s" >>"$log"
timeout -k 5 $((limit + 80)) "${qdrl[@]}" run "$here/../agents/qdac_walker2d_feet_contact.toml" \
    --out "$out/qdac_run" --set experiment.time_limit_s=$limit --set log.plots=false >>"$log" 2>&1
echo "{\"step\": \"qdac\", \"rc\": $?}" | tee -a "$log"
cp "$out/qdac_run/summary.json" "$out/qdac_summary.json" 2>/dev/null

echo "=== qdrl bench skill_methods" >>"$log"
timeout -k 5 200 "${qdrl[@]}" bench skill_methods "${quick[@]}" --out "$out/skill_methods.json" >>"$log" 2>&1
echo "{\"step\": \"bench\", \"rc\": $?}" | tee -a "$log"
