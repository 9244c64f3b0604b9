# Sourced by the other scripts: a PATH where Debian's python3 comes first (a pyenv python3 breaks
# catkin and rostest), and the workspace the package is built in.
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
REPO_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS_DIR="${MODAL_WS:-/tmp/modal_mass_spring_ws}"
export REPO_DIR WS_DIR
