#!/usr/bin/env bash
# The GPU measurements of the skill-discovery benchmark (Chalumeau, Boige et al. 2023), as one
# script under 8 minutes:
#
#   bash benchmarks/gpu_seed_benchmark.sh OUT_DIR
#
# 1. MAP-Elites and SMERL (DIAYN) on ant_omni at the study's full settings
#    (agents/seed_benchmark/{map_elites,smerl_diayn}_ant_omni.toml: batch 1000, 200 environments,
#    one gradient step per environment step), each for a fixed wall time (experiment.time_limit_s,
#    75 s), then environment steps per hour beside the QDax paper's Table 2 (a Quadro RTX 4000:
#    MAP-Elites 1.7e9 and SMERL 1.01e7 environment steps in two hours on ant_omni);
# 2. PGA-ME against MAP-Elites on halfcheetah_uni at the study's settings, one seed, 5,000
#    evaluations each (benchmarks/pga_me_study_vs_qdax.py; QDax 0.5.0 too where QDAX_PY is set).
#
# Environment: PY (python with qdrl importable; default python3), QDAX_PY (python with
# qdax==0.5.0; default none), PLATFORM (JAX_PLATFORMS: cuda, or cpu to try the mechanics),
# QUICK=1 (the `_cpu` specs for 20 s, SMERL logging every 2,000 steps; 2,000 evaluations).
# Output: OUT_DIR/log.txt, OUT_DIR/{map_elites,smerl_diayn}_summary.json, OUT_DIR/table2.json,
# OUT_DIR/pga_me_study.json.
set -u
source "$(dirname "$0")/gpu_env.sh" "$@"
if [[ ${QUICK:-0} == 1 ]]; then limit=20; suffix=_cpu; evaluations=2000; study_limit=400
else limit=75; suffix=; evaluations=5000; study_limit=150; fi
qdrl=("$py" -c "import sys; from qdrl.cli import main; sys.exit(main(sys.argv[1:]))")

for algorithm in map_elites smerl_diayn; do
    spec=$here/../agents/seed_benchmark/${algorithm}_ant_omni${suffix}.toml
    echo "=== ${algorithm}_ant_omni${suffix} for ${limit} s" >>"$log"
    extra=(); [[ ${QUICK:-0} == 1 && $algorithm == smerl_diayn ]] && extra=(--set train.eval_every=2000)
    timeout -k 5 $((limit + 90)) "${qdrl[@]}" run "$spec" --out "$out/${algorithm}_run" \
        --time-limit $limit --set log.plots=false "${extra[@]}" >>"$log" 2>&1
    echo "{\"step\": \"$algorithm\", \"rc\": $?}" | tee -a "$log"
    cp "$out/${algorithm}_run/summary.json" "$out/${algorithm}_summary.json" 2>/dev/null
done

# environment steps an hour (compilation excluded) beside Table 2's two-hour figures
"$py" - "$out" <<'EOF' | tee "$out/table2.json"
import json, sys
from pathlib import Path
out, table2 = Path(sys.argv[1]), {"map_elites": 1.7e9, "smerl_diayn": 1.01e7}
rows = {}
for algorithm, two_hours in table2.items():
    path = out / f"{algorithm}_summary.json"
    if not path.is_file():
        continue
    s = json.loads(path.read_text())
    per_hour = s["env_steps"] / s["run_s"] * 3600 if s.get("run_s") else None
    rows[algorithm] = {"env_steps": s["env_steps"], "run_s": s["run_s"], "compile_s": s.get("compile_s"),
                       "steps_per_hour": per_hour, "qdax_paper_steps_per_hour": two_hours / 2,
                       "over_qdax_paper": per_hour / (two_hours / 2) if per_hour else None}
print(json.dumps(rows, indent=1))
EOF

echo "=== pga_me_study_vs_qdax halfcheetah_uni, ${evaluations} evaluations" >>"$log"
qdax=(); [[ -n ${QDAX_PY:-} ]] && qdax=(--qdax-python "$QDAX_PY")
timeout -k 5 $study_limit "$py" "$here/pga_me_study_vs_qdax.py" "${qdax[@]}" --tasks halfcheetah_uni --seeds 1 \
    --evaluations $evaluations --out "$out/pga_me_study.json" --plots "$out" >>"$log" 2>&1
echo "{\"step\": \"pga_me_study\", \"rc\": $?}" | tee -a "$log"
