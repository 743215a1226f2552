#!/usr/bin/env bash
# Runs the test suites (all by default, or the ones named: cpp python ros) and fails when any
# suite fails or runs no test. Expects scripts/setup.sh to have run (make test does that).
set -eo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
suites=("$@")
[ ${#suites[@]} -eq 0 ] && suites=(cpp python ros)
for suite in "${suites[@]}"; do
  case "$suite" in
    cpp)
      echo "=== ctest (C++ core)"
      # scripts/setup.sh built the gtests in the same tree as the Python module (one compile).
      ctest --test-dir build/py --output-on-failure --no-tests=error -j2
      ;;
    python)
      echo "=== pytest"
      "$VENV/bin/python" -m pytest -q tests/python
      ;;
    ros)
      if [ -x ros1_pkg/scripts/run_rostests.sh ]; then
        echo "=== rostest (ROS 1 node)"
        bash ros1_pkg/scripts/run_rostests.sh
      else
        echo "=== rostest: no ROS package yet"
      fi
      ;;
    *) echo "unknown suite '$suite' (cpp python ros)"; exit 2 ;;
  esac
done
