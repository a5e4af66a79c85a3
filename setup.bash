# Source this file (`source setup.bash`) to use the workspace: ROS 2 (real or the venv's wheels),
# the virtual environment, the built packages and the `ros2` command.
_ops_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
if [ -f "${OPS_ROS_DIR:-/opt/ros/jazzy}/setup.bash" ]; then
  # shellcheck disable=SC1091
  source "${OPS_ROS_DIR:-/opt/ros/jazzy}/setup.bash"
fi
if [ ! -x "$_ops_root/.venv/bin/python" ] || [ ! -f "$_ops_root/install/setup.bash" ]; then
  echo "setup.bash: the workspace is not set up yet; run 'make setup' first" >&2
else
  export VIRTUAL_ENV="$_ops_root/.venv"
  case ":$PATH:" in
    *":$VIRTUAL_ENV/bin:"*) ;;
    *) export PATH="$VIRTUAL_ENV/bin:$PATH" ;;
  esac
  # shellcheck disable=SC1091
  source "$_ops_root/install/setup.bash"
  # Fast DDS repairs a lost message within 50 ms instead of 3 s (config/fastdds_profile.xml).
  export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_ops_root/config/fastdds_profile.xml}"
  # Tab completion of `ros2` (argcomplete) in interactive bash.
  if [ -n "${BASH_VERSION:-}" ] && [ -x "$VIRTUAL_ENV/bin/register-python-argcomplete" ]; then
    eval "$("$VIRTUAL_ENV/bin/register-python-argcomplete" ros2)"
  fi
fi
unset _ops_root
