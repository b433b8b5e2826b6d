#!/usr/bin/env bash
# Full default test suite on the lent GPU, log kept under $OUT.
export XLA_PYTHON_CLIENT_PREALLOCATE=false XLA_FLAGS=--xla_gpu_autotune_level=0 PYTHONPATH=$PWD
OUT=${OUT:-.}
nvidia-smi -L | tee $OUT/log
python -c "import jax, sys; print(sys.version); print(jax.__version__, jax.devices())" 2>&1 | tee -a $OUT/log
python -c "import xdist" 2>/dev/null && N="-n 8" || N=""
echo "xdist: $N" | tee -a $OUT/log
timeout 480 python -m pytest -v $N -m "not slow" -p no:cacheprovider --durations=20 -o console_output_style=classic 2>&1 | tee -a $OUT/log | grep -E "FAILED|ERROR|passed|failed" | tail -40
grep -E "FAILED|ERROR" $OUT/log | sort | uniq | head -40
