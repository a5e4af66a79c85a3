#!/usr/bin/env bash
# A stacker driven through its instruments, headless (docs/rig.md): the simulated lab (N = 5,
# hard mode, a fixed seed) with its scope over SCPI/TCP and piezo drives on pseudo-terminals,
# `calibrate`, the `rig` node and the `tracker` (its nominal optics from the rig YAML) close the
# loop over DDS for DEMO_SECONDS while the monitor records the trace and P_N/P_max.
# Output: runs/demo_rig/monitor.png (first trace / latest trace / P_N history, the tracker's start
# marked), rig.yaml and logs. The monitor stops first, so "after" is a controlled trace.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash

OUT="${DEMO_OUT:-runs/demo_rig}"
SECONDS_TO_RUN="${DEMO_SECONDS:-40}"
SEED="${DEMO_SEED:-1}"
RATE_HZ="${DEMO_RATE_HZ:-50}"
# Extra tracker parameters, e.g. DEMO_TRACKER_ARGS="-p hop_every:=0".
read -r -a TRACKER_ARGS <<<"${DEMO_TRACKER_ARGS:-}"
mkdir -p "$OUT"
rm -f "$OUT"/*.log "$OUT/monitor.png" "$OUT/rig.yaml"
# A domain of its own, so the demo does not meet other ROS 2 programs on this network.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 90 + 10))}"

# Stopped in the reverse order of their start: the controller and the monitor first, then the
# rig (which parks the piezos), the simulated lab last (the park needs its piezo drives).
pids=()
stop_all() {
  local i
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
    kill -INT "${pids[i]}" 2>/dev/null || true
    wait "${pids[i]}" 2>/dev/null || true
  done
  pids=()
}
trap stop_all EXIT

DEMO_TAG=demo-rig
# shellcheck source=scripts/demo_lib.sh
source scripts/demo_lib.sh  # wait_for_line (the working directory is the root)

echo "[demo-rig] ROS_DOMAIN_ID=$ROS_DOMAIN_ID; simulated lab: stage 5, hard, seed $SEED, ${RATE_HZ} Hz"
ros2 run ops_rig_ros simlab --stage 5 --mode hard --seed "$SEED" --rate-hz "$RATE_HZ" \
  --config-out "$OUT/rig.yaml" >"$OUT/simlab.log" 2>&1 &
pids+=($!)
wait_for_line "$OUT/simlab.log" "simlab ready" 30

echo "[demo-rig] calibrating (sweeps and fringe fits, written into $OUT/rig.yaml)"
if ! ros2 run ops_rig_ros calibrate --ros-args -p config:="$OUT/rig.yaml" >"$OUT/calibrate.log" 2>&1; then
  echo "[demo-rig] FAILED: calibrate:" >&2
  cat "$OUT/calibrate.log" >&2
  exit 1
fi
grep "\[calibrate\]" "$OUT/calibrate.log" | tail -n 3 | sed 's/^/[demo-rig] /'

ros2 run ops_rig_ros rig --ros-args -p config:="$OUT/rig.yaml" >"$OUT/rig.log" 2>&1 &
pids+=($!)
wait_for_line "$OUT/rig.log" "scope connected" 30
# A history as long as the run, written at the end (a redraw every few seconds costs the loop).
history=$((SECONDS_TO_RUN * ${RATE_HZ%.*} * 2 + 100))
ros2 run ops_sim_ros monitor --ros-args -p save:="$OUT/monitor.png" -p history:="$history" \
  -p png_period_s:=3600.0 \
  -p title:="tracker on the simulated lab (N = 5, hard mode, seed $SEED, ${RATE_HZ} Hz)" \
  >"$OUT/monitor.log" 2>&1 &
monitor_pid=$!
pids+=($!)
wait_for_line "$OUT/monitor.log" "first trace received" 30
grep -o "first trace received.*" "$OUT/monitor.log" | sed "s/^/[demo-rig] before the tracker (drifted since calibrate): /"

echo "[demo-rig] starting the tracker (nominal optics from $OUT/rig.yaml) for ${SECONDS_TO_RUN} s"
ros2 run ops_controller_ros tracker --ros-args -p rig_config:="$OUT/rig.yaml" -p seed:="$SEED" \
  -p log_period_s:=5.0 "${TRACKER_ARGS[@]}" >"$OUT/tracker.log" 2>&1 &
pids+=($!)
wait_for_line "$OUT/tracker.log" "closing the loop" 30
grep -o "nominal model from.*" "$OUT/tracker.log" | sed 's/^/[demo-rig] /'
sleep "$SECONDS_TO_RUN"
grep -o "reading [0-9]* (.*" "$OUT/tracker.log" | tail -n 3 | sed "s/^/[demo-rig] /"
grep -o "true P_N/P_max.*" "$OUT/simlab.log" | tail -n 1 | sed "s/^/[demo-rig] simlab's /"

# The picture first, while the tracker still holds the stack; then the rest in reverse order.
kill -INT "$monitor_pid" && wait "$monitor_pid" || true
stop_all
trap - EXIT
grep -o "parked the piezos.*" "$OUT/rig.log" | sed 's/^/[demo-rig] rig: /' || true
grep -o "wrote .*" "$OUT/monitor.log" | sed 's/^/[demo-rig] /'
[ -f "$OUT/monitor.png" ] || { echo "[demo-rig] FAILED: no $OUT/monitor.png" >&2; exit 1; }
echo "[demo-rig] done: picture in $OUT/monitor.png, logs and rig.yaml in $OUT/"
