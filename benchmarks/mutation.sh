#!/usr/bin/env bash
# Mutation testing of the numeric core with mutmut, on the fast tests.
#
#   benchmarks/mutation.sh [MODULE ...]     e.g. benchmarks/mutation.sh lipm stop_condition newton solver
#
# Modules of drake_estop/planning/. Default: lipm stop_condition newton solver (the LIPM, the
# closed-form stop condition and its derivatives, the interior-point Newton method, grid start and
# quantisation); add planner assembly landing zmp_check replan halt for the planner and the halt
# (slower). Runs in a scratch copy of the tracked files (the work tree stays clean), with
# DRAKE_ESTOP_PURE_PYTHON=1: the solver's one
# source runs as plain Python, so the mutants need no numba compile. Needs mutmut >= 3.8 (pip install mutmut); MUTMUT_PYTHONPATH may point at a --target
# install. Not in CI: tens of minutes on two cores. Prints mutmut's per-mutant results and the
# score; the README lists the result and the surviving (equivalent) mutants.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
python=${PYTHON:-$repo/.venv/bin/python}
[ -x "$python" ] || python=python3
modules=("$@")
[ ${#modules[@]} -gt 0 ] || modules=(lipm stop_condition newton solver)
work=$(mktemp -d)
trap 'echo "mutmut workspace: $work"' EXIT
git -C "$repo" ls-files -z | (cd "$repo" && xargs -0 tar -cf -) | tar -xf - -C "$work"
cd "$work"
{
  echo "[mutmut]"
  echo "source_paths = drake_estop"
  echo "only_mutate ="
  for m in "${modules[@]}"; do echo "    drake_estop/planning/$m.py"; done
  echo "also_copy ="
  echo "    tests"
  echo "    models"
  echo "    pyproject.toml"
  # the fast tests (test_solver's compiled-vs-Python comparison skips itself: nothing is compiled);
  # left out: three slow ones that only repeat what others check
  echo "pytest_add_cli_args ="
  for arg in -p no:cacheprovider -k "not 1e-06" \
             --deselect tests/test_planner.py::test_one_step_wherever_feasible \
             --deselect tests/test_planner.py::test_logged_cog_obeys_lipm_by_independent_integration; do
    echo "    $arg"
  done
  echo "pytest_add_cli_args_test_selection ="
  for t in test_lipm test_stop_condition test_newton test_solver test_planner test_short_steps test_properties test_gait; do
    echo "    tests/$t.py"
  done
} > setup.cfg
export DRAKE_ESTOP_PURE_PYTHON=1
export PYTHONPATH="${MUTMUT_PYTHONPATH:+$MUTMUT_PYTHONPATH:}$work"
"$python" -m mutmut run --max-children "${MUTMUT_CHILDREN:-2}"
"$python" -m mutmut results --all true > results.txt || true
"$python" - <<'PY'
import collections, re
counts = collections.Counter()
for line in open("results.txt"):
    m = re.match(r"\s*(\S+): (\S+)", line)
    if m:
        counts[m.group(2)] += 1
total = sum(counts.values())
killed = counts["killed"] + counts["timeout"]
print(dict(counts))
if total:
    print(f"mutation score: {killed}/{total} = {100 * killed / total:.1f} % (killed or timed out)")
PY
