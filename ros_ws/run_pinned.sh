#!/usr/bin/env bash
# Run a long job (data generation, training, the benchmark) on the code of one commit,
# so that edits to the working tree cannot change it while it runs:
#   ros_ws/run_pinned.sh COMMIT LOG -- COMMAND...
# makes (or reuses) the worktree out/pinned/<commit>, puts its packages first on
# PYTHONPATH (spawned workers inherit it) and starts COMMAND with nohup from the
# project root, so relative --out paths still land in this checkout.  Rerun the same
# line after a stop: the data commands resume.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
[ $# -ge 4 ] && [ "$3" = "--" ] || { echo "usage: ros_ws/run_pinned.sh COMMIT LOG -- COMMAND..." >&2; exit 2; }
commit="$(git -C "$root" rev-parse --verify --quiet "$1^{commit}")" \
  || { echo "run_pinned.sh: '$1' names no commit of $root (give a hash or HEAD; git log --oneline lists them)" >&2; exit 2; }
log="$2"; shift 3
wt="$root/out/pinned/${commit:0:12}"
[ -d "$wt" ] || git -C "$root" worktree add --detach "$wt" "$commit" >/dev/null
set +u; source "$root/ros_ws/env.sh"; set -u
export PYTHONPATH="$wt/sim_bridge:$wt/gravgrasp_detector:$wt/robotiq_driver:${PYTHONPATH:-}"
cd "$root"
mkdir -p "$(dirname "$log")"
nohup "$@" >> "$log" 2>&1 &
echo "started pid $! on ${commit:0:12} ($wt); log: $log"
