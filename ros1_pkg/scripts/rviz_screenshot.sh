#!/usr/bin/env bash
# Starts demo.launch (small bay, node, robot_state_publisher, rviz) under a virtual screen, waits for
# the plan, lets the execution run a few seconds (arm moving, wall filling up), saves a screenshot
# of the screen and fails when the 3D view is blank.
# Usage: rviz_screenshot.sh OUT.png
# Env: SMALL=true for the small crown strip (default: the whole default bay), SHOT_DELAY_S (default 8),
#      LOOP=true for demo.launch loop:=true: the shot once the rescan reported (measured layer and
#      corrective passes on screen)
set -eo pipefail
OUT=${1:?usage: rviz_screenshot.sh OUT.png}
PKG_DIR="$(cd "$(dirname "$0")/.." && pwd)"
WS="$PKG_DIR/.ws"
mkdir -p "$(dirname "$OUT")"
OUT="$(cd "$(dirname "$OUT")" && pwd)/$(basename "$OUT")"
if [ ! -x "$WS/devel/lib/shotcrete_ros/shotcrete_node" ]; then
  BUILD_ONLY=1 bash "$PKG_DIR/scripts/run_rostests.sh"
fi
# shellcheck disable=SC1091
source "$WS/devel/setup.bash"
ROS_HOME="$(mktemp -d /tmp/shotcrete-rviz.XXXXXX)"
export ROS_HOME
trap 'rm -rf "$ROS_HOME"' EXIT
# A free port of our own: never disturb another master (or another test run).
PORT=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$PORT"
export SHOT_OUT="$OUT" SHOT_DELAY_S="${SHOT_DELAY_S:-8}" SHOT_SMALL="${SMALL:-false}" SHOT_LOOP="${LOOP:-false}" PKG_DIR
rm -f "$OUT"

xvfb-run -a -s "-screen 0 1280x900x24" bash -c '
  set -e
  roslaunch -p "${ROS_MASTER_URI##*:}" shotcrete_ros demo.launch small:="$SHOT_SMALL" loop:="$SHOT_LOOP" max_wall_s:=30 \
    >"$ROS_HOME/demo.log" 2>&1 &
  launch=$!
  stop() { kill -INT $launch 2>/dev/null || true; wait $launch 2>/dev/null || true; }
  trap stop EXIT
  if ! summary=$(/usr/bin/python3 "$PKG_DIR/scripts/wait_for_message.py" /shotcrete_node/summary 120 2>>"$ROS_HOME/demo.log" | tail -n 1); then
    echo "[screenshot] no plan summary; demo log:"; tail -40 "$ROS_HOME/demo.log"; exit 1
  fi
  # The summary is the job summary JSON: show the verdict, not the whole document.
  echo "[screenshot] plan: $(printf "%s" "$summary" | /usr/bin/python3 -c "import json, sys; s = json.load(sys.stdin); print(\"cells\", s[\"cells\"], \"levels after\", s[\"levels_after\"], \"residual rms mm\", round(s[\"residual_mm\"][\"rms\"], 2), \"passes\", s[\"passes\"])" 2>/dev/null || printf "%.200s" "$summary")"
  if [ "$SHOT_LOOP" = true ]; then
    if ! status=$(/usr/bin/python3 "$PKG_DIR/scripts/wait_for_message.py" /shotcrete_node/rescan_status 300 2>>"$ROS_HOME/demo.log" | tail -n 1); then
      echo "[screenshot] no rescan status; demo log:"; tail -40 "$ROS_HOME/demo.log"; exit 1
    fi
    echo "[screenshot] rescan: $(printf "%s" "$status" | /usr/bin/python3 -c "import json, sys; s = json.load(sys.stdin); print(\"flow factor\", s[\"calibration\"].get(\"flow_factor\"), \"layer mm\", round(s[\"thickness_mm\"][\"mean\"], 1), \"corrective passes\", (s[\"correction\"] or {}).get(\"passes\"))" 2>/dev/null || printf "%.200s" "$status")"
  fi
  sleep "$SHOT_DELAY_S"
  # rviz can take a while for its first frame on a loaded machine: a screen of one colour is
  # taken again (up to 4 times, 10 s apart); the check below judges the last shot.
  for attempt in 1 2 3 4; do
    import -window root "$SHOT_OUT"
    [ "$(convert "$SHOT_OUT" -format "%k" info:)" -gt 50 ] && break
    echo "[screenshot] shot $attempt is one colour (rviz not drawn yet); again in 10 s"
    sleep 10
  done
'

# Not blank: background (40, 40, 48) and the floor grid are grey; the robot, the TD-coloured wall
# and the markers are saturated colours. Require them in the middle of the 3D view.
region="820x600+400+120"
saturated=$(convert "$OUT" -crop "$region" +repage -colorspace HSL -channel G -separate +channel \
  -threshold 35% -format "%[fx:mean]" info:)
colours=$(convert "$OUT" -crop "$region" +repage -format "%k" info:)
stddev=$(identify -format "%[standard-deviation]" "$OUT")
echo "[screenshot] $OUT: saturated share $saturated, $colours colours in the 3D view, std dev $stddev"
awk -v f="$saturated" -v c="$colours" 'BEGIN { exit !(f > 0.01 && c > 50) }' \
  || { echo "[screenshot] FAILED: the 3D view shows no robot, wall or markers"; exit 1; }
