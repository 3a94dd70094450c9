# Source this file to get the venv and the built workspace: `source scripts/env.sh`.
_katana_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
# shellcheck disable=SC1091
source "$_katana_root/.venv/bin/activate"
export AMENT_PREFIX_PATH=${AMENT_PREFIX_PATH:-$VIRTUAL_ENV}
# colcon's setup script warns that the venv has no local_setup file; that is harmless.
# shellcheck disable=SC1091
source "$_katana_root/install/setup.bash" 2>/dev/null
unset _katana_root
# Console scripts install to install/<pkg>/lib/<pkg> (where `ros2 run` looks); put them on PATH
# too, since `ros2` itself is not available from PyPI.
for _katana_bin in "$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"/install/*/lib/*/; do
  case ":$PATH:" in *":${_katana_bin%/}:"*) ;; *) PATH="${_katana_bin%/}:$PATH" ;; esac
done
unset _katana_bin
export PATH
