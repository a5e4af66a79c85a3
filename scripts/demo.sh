#!/usr/bin/env bash
# The main job, headless: the simulator (N = 5, easy mode) and the SPGD-PID controller close the
# loop over DDS for a few seconds while the monitor records the trace before and after.
# Output: runs/demo/monitor.png (before / after / P_N history, the controller's start marked)
# and the controller's log lines. The monitor stops first, so "after" is a controlled trace.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash

OUT="${DEMO_OUT:-runs/demo}"
SECONDS_TO_RUN="${DEMO_SECONDS:-6}"
mkdir -p "$OUT"
rm -f "$OUT"/*.log "$OUT/monitor.png"
# A domain of its own, so the demo does not meet other ROS 2 programs on this network.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 90 + 10))}"

pids=()
stop_all() {
  for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
}
trap stop_all EXIT

DEMO_TAG=demo
# shellcheck source=scripts/demo_lib.sh
source scripts/demo_lib.sh  # wait_for_line (the working directory is the root)

echo "[demo] ROS_DOMAIN_ID=$ROS_DOMAIN_ID; starting the simulator (stage 5, easy mode)"
ros2 run ops_sim_ros sim --ros-args -p stage:=5 -p mode:=easy -p seed:=7 >"$OUT/sim.log" 2>&1 &
pids+=($!)
ros2 run ops_sim_ros monitor --ros-args -p save:="$OUT/monitor.png" \
  -p title:="SPGD-PID on the simulator (N = 5, easy mode, seed 7)" >"$OUT/monitor.log" 2>&1 &
monitor_pid=$!
pids+=($!)
wait_for_line "$OUT/monitor.log" "first trace received" 30
grep -o "first trace received.*" "$OUT/monitor.log" | sed 's/^/[demo] before control: /'

echo "[demo] starting the SPGD-PID controller for ${SECONDS_TO_RUN} s"
ros2 run ops_controller_ros spgd --ros-args -p seed:=7 -p log_period_s:=0.1 \
  >"$OUT/spgd.log" 2>&1 &
pids+=($!)
wait_for_line "$OUT/spgd.log" "closing the loop" 30
sleep "$SECONDS_TO_RUN"
grep -o "iteration .*" "$OUT/spgd.log" | head -n 4 | sed "s/^/[demo] /"
echo "[demo] ..."
grep -o "iteration .*" "$OUT/spgd.log" | tail -n 3 | sed "s/^/[demo] /"
echo "[demo] (all lines in $OUT/spgd.log)"

# The picture first, while the controller still holds the stack; then the rest.
kill -INT "$monitor_pid" && wait "$monitor_pid" || true
stop_all
trap - EXIT
cat "$OUT/monitor.log" | grep -o "wrote .*" | sed 's/^/[demo] /'
[ -f "$OUT/monitor.png" ] || { echo "[demo] FAILED: no $OUT/monitor.png" >&2; exit 1; }
echo "[demo] done: picture in $OUT/monitor.png, logs in $OUT/"
