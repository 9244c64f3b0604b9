# Sourced by the other scripts: a PATH where Debian's python3 comes first (a pyenv python3 breaks
# catkin and rostest), and the workspace the package is built in.
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS_DIR="${MODAL_WS:-/tmp/modal_mass_spring_ws}"
# Parallel compile jobs: 2 by default (the machines this is built on have 2 cores); MODAL_JOBS=1 on
# a shared or small machine.
JOBS="${MODAL_JOBS:-2}"
if ! [[ "$JOBS" =~ ^[1-9][0-9]*$ ]]; then
  echo "MODAL_JOBS='$JOBS': must be a whole number of compile jobs >= 1" >&2
  exit 2
fi
export REPO_DIR WS_DIR JOBS
