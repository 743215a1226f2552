#!/usr/bin/env bash
# Idempotent set-up on Debian 12 as root: system packages (apt), a venv with the Python
# dependencies (PyPI), then the project built and installed into the venv.
# Usage: scripts/setup.sh [--no-ros] ; VENV=.venv by default.
set -eo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}

APT_PACKAGES=(
  build-essential cmake ninja-build ccache python3-venv python3-dev pkg-config
  libeigen3-dev libpcl-dev liborocos-kdl-dev libkdl-parser-dev liburdf-dev libnlopt-cxx-dev libfcl-dev
  libgtest-dev libyaml-cpp-dev
  catkin libroscpp-dev libsensor-msgs-dev libvisualization-msgs-dev libstd-srvs-dev
  libpcl-conversions-dev librostest-dev python3-rostest python3-rospy python3-roslaunch
  ros-robot-state-publisher python3-sensor-msgs python3-visualization-msgs python3-std-srvs
  python3-tf2-msgs libtf2-msgs-dev rviz xvfb xauth imagemagick
  chromium  # the report page's browser test (scripts/check_report_page.py)
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "[setup] installing ${#missing[@]} Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  # With recommends, as verified: rviz under Xvfb needs the Mesa drivers and fonts they bring.
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${missing[@]}" >/dev/null
fi

# Debian's own interpreter: its headers come from python3-dev above, on every machine.
if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating venv $VENV"
  /usr/bin/python3 -m venv "$VENV"
fi
stamp="$VENV/.deps-$(sha1sum pyproject.toml | cut -c1-12)"
if [ ! -f "$stamp" ]; then
  echo "[setup] installing Python dependencies"
  "$VENV/bin/pip" install -q --upgrade pip
  "$VENV/bin/pip" install -q "scikit-build-core>=0.10" "pybind11>=2.12" \
    numpy pyyaml typer rich matplotlib plotly laspy lazrs pye57 ezdxf scipy pytest
  touch "$stamp"
fi

echo "[setup] building and installing shotcrete into $VENV"
export CMAKE_CXX_COMPILER_LAUNCHER=ccache
"$VENV/bin/pip" install -q --no-build-isolation --no-deps -e . \
  -Cbuild-dir=build/py -Ccmake.define.BUILD_TESTING=ON
