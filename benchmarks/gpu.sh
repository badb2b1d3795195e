#!/usr/bin/env bash
# The accelerator benchmarks in one run: scaling to large populations, simulate_batch's XLA program
# and the fused kernel (jaxflex.fused), then identify and discover on ROTFLEX (cold and warm
# compilation cache). Usage: benchmarks/gpu.sh OUT_DIR [LABEL]
# Needs jaxflex importable (installed, or PYTHONPATH=.) and the ROTFLEX records reachable
# (JAXFLEX_DATA_DIR or the network). Each step is bounded in time so that the others still run.
set -u
out=${1:?usage: benchmarks/gpu.sh OUT_DIR [LABEL]}
label=${2:-gpu}
mkdir -p "$out"
export JAXFLEX_PROGRESS=0 PYTHONUNBUFFERED=1
python3 -c "import jax, jaxflex; print('jax', jax.__version__, jax.devices())"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
for program in scan fused; do
    timeout 100 python3 benchmarks/scaling.py --axes population --populations 1 10000 100000 \
        --program "$program" --out "$out/scaling_${program}_$label.json"
done
timeout 300 python3 benchmarks/time_to_answer.py --label "$label" \
    --only help identify_rotflex discover_rotflex
cp benchmarks/results/time_to_answer.json "$out/time_to_answer.json"
