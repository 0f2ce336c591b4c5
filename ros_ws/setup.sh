#!/usr/bin/env bash
# One-stop setup on a fresh Debian 12 machine: Debian packages, the Python 3.11 venv
# with exactly the pins in requirements.lock, the CMake repair the ros-jazzy wheels
# need, and the colcon build. Each step is skipped when its inputs are unchanged, so a
# second run takes seconds.
set -euo pipefail
ws="$(cd "$(dirname "$0")" && pwd)"
root="$(dirname "$ws")"
stamps="$root/.setup-stamps"
mkdir -p "$stamps"
say() { echo "[setup] $*"; }

# 1. Debian packages: compilers for the interface build, libusb for open3d, socat for
#    the gripper emulator's pseudo-terminals.
debs=(cmake g++ make socat libusb-1.0-0 python3-venv)
missing=()
for p in "${debs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  sudo_cmd=""; [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  say "installing Debian packages: ${missing[*]}"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# 2. The venv, Python 3.11 (the ros-jazzy wheels are cp311).
py="${PYTHON:-$(command -v python3.11 || command -v python3)}"
if ! "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "[setup] error: Python 3.11 is required (found $("$py" --version 2>&1) at $py); install python3.11 or set PYTHON=/path/to/python3.11" >&2
  exit 1
fi
if [ ! -x "$root/.venv/bin/python" ]; then
  say "creating .venv with $py"
  "$py" -m venv "$root/.venv"
  rm -f "$stamps/requirements"
fi

# 3. Exact pins. torch==2.13.0 resolves to the CPU build on this machine's disk.
#    --no-compile: byte-compiling every installed module took ~1/3 of the install; Python
#    compiles (and caches) only the modules that are imported, on their first import.
lock_sum="$(sha256sum "$root/requirements.lock" | cut -d' ' -f1)"
if [ "$(cat "$stamps/requirements" 2>/dev/null)" != "$lock_sum" ]; then
  say "installing requirements.lock (first time: a few minutes)"
  if ! "$root/.venv/bin/pip" install -q --no-compile --disable-pip-version-check -r "$root/requirements.lock" \
      > "$stamps/pip-install.log" 2>&1; then
    grep -v "^WARNING: Location" "$stamps/pip-install.log" | tail -20 >&2
    echo "[setup] error: pip install failed; full log in $stamps/pip-install.log" >&2
    exit 1
  fi
  "$root/.venv/bin/python" "$ws/repair_wheel_cmake.py"
  echo "$lock_sum" > "$stamps/requirements"
fi

# 4. colcon build (symlink install: Python edits need no rebuild).
# colcon's generated scripts read unset variables.
set +u
# shellcheck disable=SC1091
source "$ws/env.sh"
set -u
cd "$ws"
if ! colcon build --symlink-install --event-handlers console_direct- \
    --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VIRTUAL_ENV/bin/python" \
    > "$stamps/colcon-build.log" 2>&1; then
  tail -40 "$stamps/colcon-build.log" >&2
  echo "[setup] error: colcon build failed; full log in $stamps/colcon-build.log" >&2
  exit 1
fi
say "ready: source ros_ws/env.sh for a ROS 2 shell"
