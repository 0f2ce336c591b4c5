# Source this file for a ROS 2 Jazzy shell on the gravgrasp workspace:
#   source ros_ws/env.sh
# It activates the project venv (the ros-jazzy-* wheels), points the ament index at
# it, keeps ROS logs inside the project, restricts discovery to this machine, and
# overlays the colcon install (if built).
_gg_ws="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
_gg_root="$(dirname "$_gg_ws")"
export GRAVGRASP_ROOT="$_gg_root"
export VIRTUAL_ENV="$_gg_root/.venv"
case ":$PATH:" in *":$VIRTUAL_ENV/bin:"*) ;; *) export PATH="$VIRTUAL_ENV/bin:$PATH" ;; esac
# Nothing in the wheels sets this; without it rclpy cannot find message packages.
case ":${AMENT_PREFIX_PATH:-}:" in
  *":$VIRTUAL_ENV:"*) ;;
  *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;;
esac
export ROS_HOME="${ROS_HOME:-$_gg_ws/.ros}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-$ROS_HOME/log}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export RCUTILS_COLORIZED_OUTPUT=0
if [ -f "$_gg_ws/install/local_setup.bash" ] && [ -n "${BASH_VERSION:-}" ]; then
  # shellcheck disable=SC1091
  COLCON_CURRENT_PREFIX="$_gg_ws/install" . "$_gg_ws/install/local_setup.bash"
fi
# `ros2 run <pkg> <exe>` for this workspace (ros2cli is not on PyPI; on an apt install
# of Jazzy the real ros2 command is used instead).
if ! command -v ros2 >/dev/null 2>&1 || [ "$(command -v ros2)" = "$_gg_ws/bin/ros2" ]; then
  case ":$PATH:" in *":$_gg_ws/bin:"*) ;; *) export PATH="$_gg_ws/bin:$PATH" ;; esac
fi
unset _gg_ws _gg_root
