#!/usr/bin/env bash
# Same problem, same run: eyekey's FISTA against SciPy's L-BFGS-B (the 2014 vision-correcting display's solver).
# Installs its own Python dependencies into benches/.venv. Usage: bash benches/solver_vs_scipy.sh [preset]
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:-paper}"
python3 -m venv benches/.venv >/dev/null 2>&1 || true
benches/.venv/bin/pip install -q numpy scipy
cargo build --release -q
dir=$(mktemp -d)
./target/release/eyekey bench --preset "$preset" --section solver --export "$dir"
benches/.venv/bin/python benches/scipy_lbfgsb.py "$dir" | tee "$dir/scipy.json"
body=$(benches/.venv/bin/python - "$dir/scipy.json" "$preset" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
print(f"Problem: `{sys.argv[2]}` preset, multiplex with 2 observers, exported as Matrix Market ({r['rows']}×{r['cols']}, {r['nnz']} non-zeros, "
      f"C⊗T expanded). SciPy {r['scipy_version']} L-BFGS-B (maxcor 10) from the same start, same objective, measured in the same run by "
      "`bash benches/solver_vs_scipy.sh`.\n")
print("| solver | time to f*(1+1e-3) | evaluations | final objective |")
print("| --- | --- | --- | --- |")
print(f"| eyekey FISTA (fused C⊗T kernels) | {r['eyekey_seconds_to_1e-3']:.2f} s | – | {r['eyekey_f_star']:.4e} |")
s = r['scipy_seconds_to_1e-3']
print(f"| SciPy L-BFGS-B | {('%.2f s' % s) if s else 'not reached in ' + ('%.1f s' % r['scipy_total_seconds'])} | {r['scipy_evaluations_to_1e-3'] or r['scipy_evaluations']} | {r['scipy_final_f']:.4e} (best seen) |")
if not s:
    print(f"\nSciPy did not reach eyekey's objective within its cap ({r['scipy_message']}); the ratio is at least "
          f"{r['scipy_total_seconds'] / r['eyekey_seconds_to_1e-3']:.0f}×.")
if r.get("ratio_scipy_over_eyekey"):
    print(f"\nRatio SciPy / eyekey: **{r['ratio_scipy_over_eyekey']:.1f}×**")
PY
)
echo "$body" | python3 benches/write_section.py scipy
rm -rf "$dir"
