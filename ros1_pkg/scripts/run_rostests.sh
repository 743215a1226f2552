#!/usr/bin/env bash
# Builds the catkin package shotcrete_ros in ros1_pkg/.ws (Debian's ROS 1, /usr/bin/cmake,
# /usr/bin/python3), runs every rostest in test/ one at a time (they share the master port), then
# the rviz screenshot check. Exits non-zero when the build, any test or the screenshot fails, or
# when no test ran. SKIP_SCREENSHOT=1 leaves the screenshot out.
set -eo pipefail
PKG_DIR="$(cd "$(dirname "$0")/.." && pwd)"
WS="$PKG_DIR/.ws"
JOBS=${JOBS:-2}
mkdir -p "$WS/src"
ln -sfn "$PKG_DIR" "$WS/src/shotcrete_ros"
ln -sfn /usr/share/catkin/cmake/toplevel.cmake "$WS/src/CMakeLists.txt"
elapsed() { awk -v a="$1" -v b="$(date +%s%N)" 'BEGIN { printf "%.1f", (b - a) / 1e9 }'; }

t0=$(date +%s%N)
echo "[rostest] catkin build in $WS"
/usr/bin/cmake -S "$WS/src" -B "$WS/build" -G Ninja \
  -DCATKIN_DEVEL_PREFIX="$WS/devel" -DCMAKE_INSTALL_PREFIX="$WS/install" \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCATKIN_ENABLE_TESTING=ON \
  -DCMAKE_CXX_COMPILER_LAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER:-ccache} >"$WS/configure.log" 2>&1 \
  || { cat "$WS/configure.log"; echo "[rostest] FAILED: catkin configure"; exit 1; }
/usr/bin/cmake --build "$WS/build" -j"$JOBS" --target shotcrete_node shotcrete_ros_generate_messages \
  || { echo "[rostest] FAILED: catkin build"; exit 1; }
echo "[rostest] catkin build $(elapsed "$t0") s"
[ "${BUILD_ONLY:-0}" = 1 ] && exit 0

# devel/setup.bash is not written for `set -u`.
# shellcheck disable=SC1091
source "$WS/devel/setup.bash"
ROS_HOME="$(mktemp -d /tmp/shotcrete-roshome.XXXXXX)"
export ROS_HOME
trap 'rm -rf "$ROS_HOME"' EXIT

passed=0; failed=0; failed_names=(); rostests=0
for test_file in "$PKG_DIR"/test/*.test; do
  [ -e "$test_file" ] || continue
  rostests=$((rostests + 1))
  name=$(basename "$test_file")
  ts=$(date +%s%N)
  echo "[rostest] $name"
  log="$ROS_HOME/$name.log"
  # rostest's exit code alone misses a test script that died before reporting: also require its
  # summary to say SUCCESS with at least one test.
  if rostest shotcrete_ros "$name" >"$log" 2>&1 && grep -q "RESULT: SUCCESS" "$log" \
      && grep -Eq "TESTS: [1-9]" "$log"; then
    passed=$((passed + 1)); verdict=ok
  else
    failed=$((failed + 1)); failed_names+=("$name"); verdict=FAILED
    cat "$log"
  fi
  grep -E "^\[shotcrete_ros\.|^ \* (TESTS|ERRORS|FAILURES)" "$log" | sed 's/^/    /' || true
  printf '[rostest] %s %s in %s s\n' "$name" "$verdict" "$(elapsed "$ts")"
done

if [ "${SKIP_SCREENSHOT:-0}" != 1 ]; then
  ts=$(date +%s%N)
  shot="$(cd "$PKG_DIR/.." && pwd)/out/rviz.png"
  if bash "$PKG_DIR/scripts/rviz_screenshot.sh" "$shot"; then
    passed=$((passed + 1)); verdict=ok
  else
    failed=$((failed + 1)); failed_names+=("rviz_screenshot"); verdict=FAILED
  fi
  printf '[rostest] rviz screenshot %s in %s s (%s)\n' "$verdict" "$(elapsed "$ts")" "$shot"
fi

printf '[rostest] %d passed, %d failed%s in %s s\n' "$passed" "$failed" \
  "${failed_names:+ (${failed_names[*]})}" "$(elapsed "$t0")"
[ "$rostests" -gt 0 ] || { echo "[rostest] FAILED: no rostest ran"; exit 1; }
[ "$failed" -eq 0 ]
