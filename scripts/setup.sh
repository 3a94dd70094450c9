#!/usr/bin/env bash
# Creates .venv, installs requirements.txt, repairs the ROS wheels' CMake exports, builds ros2_ws.
# Idempotent: each stage is skipped when its inputs have not changed since it last succeeded.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
venv=$root/.venv
python=${PYTHON:-python3}

if ! "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "setup: the ROS 2 Jazzy wheels need CPython 3.11; '$python' is $("$python" --version 2>&1)." >&2
  echo "setup: set PYTHON=/path/to/python3.11 and run 'make setup' again." >&2
  exit 1
fi
for tool in cmake cc; do
  command -v "$tool" >/dev/null || { echo "setup: '$tool' is missing (apt-get install cmake build-essential)." >&2; exit 1; }
done

# Two setups at once (two terminals, parallel jobs) would corrupt the build: take turns.
mkdir -p "$root/log"
exec 9>"$root/log/.setup.lock"
flock 9

if [ ! -x "$venv/bin/python" ]; then
  echo "setup: creating $venv"
  "$python" -m venv "$venv"
fi

stamp=$venv/.requirements.sha
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing requirements.txt"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  "$venv/bin/python" -m pip install --quiet -r requirements.txt
  # The wheels' CMake exports name include folders of the machine they were built on.
  py_inc=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_inc=$("$venv/bin/python" -c 'import numpy; print(numpy.get_include())')
  { grep -rlZ --include='*.cmake' '/opt/python/cp311-cp311' "$venv/share" 2>/dev/null || true; } \
    | xargs -0 -r sed -i \
        -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
        -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g"
  echo "$want" > "$stamp"
fi

# Stand-ins of standard interfaces missing from PyPI (control_msgs, tf2_msgs: package.xml
# exports <katana_stand_in/>) are built only where no installed package provides them, so on
# a full ROS install the real one wins. A stand-in built here before would shadow it (the
# workspace overlays the underlay): remove it.
mapfile -t provided < <(VIRTUAL_ENV=$venv bash scripts/installed_stand_ins.sh "$root")
for pkg in ${provided[@]+"${provided[@]}"}; do
  echo "setup: $pkg is installed; not building the workspace's stand-in"
  rm -rf "install/$pkg" "build/$pkg"
done
skip_args=()
[ ${#provided[@]} -eq 0 ] || skip_args=(--packages-skip "${provided[@]}")

# rosidl does not notice a removed .msg/.srv/.action: its generated sources in build/ still
# name it and the build fails. An interface package whose set of interface files changed since
# its last build (or is not on record) is built afresh.
for dir in ros2_ws/src/*/; do
  pkg=$(basename "$dir")
  [ -d "build/$pkg" ] && { [ -d "${dir}msg" ] || [ -d "${dir}srv" ] || [ -d "${dir}action" ]; } \
    || continue
  now=$(cd "$dir" && ls -1 msg srv action 2>/dev/null || true)
  if [ "$(cat "build/$pkg/.interface-files" 2>/dev/null)" != "$now" ]; then
    echo "setup: the interface files of $pkg changed; building it afresh"
    rm -rf "build/$pkg" "install/$pkg"
  fi
done

# Build the workspace when any package file is newer than the last successful build.
build_stamp=$root/install/.build-ok
# Module folders are symlinked (--symlink-install), so editing or adding a module needs no build.
changed() {
  # a package that was never built (added while a build ran, or just now) needs one
  for pkg in ros2_ws/src/*/package.xml; do
    pkg=$(basename "$(dirname "$pkg")")
    case " ${provided[*]-} " in *" $pkg "*) continue ;; esac  # installed: not built here
    [ -d "install/$pkg" ] || { echo "$pkg"; return; }
  done
  find ros2_ws/src -type f -newer "$build_stamp" -not -path '*/__pycache__/*' \
    -not -path '*/.hypothesis/*' -not -path '*/test/*' \
    -not -regex 'ros2_ws/src/\([^/]*\)/\1/.*' -print -quit
}
if [ ! -f "$build_stamp" ] || [ -n "$(changed)" ]; then
  echo "setup: building ros2_ws with colcon"
  # shellcheck disable=SC1091
  source "$venv/bin/activate"
  export CMAKE_PREFIX_PATH=$venv AMENT_PREFIX_PATH=$venv
  mkdir -p log
  if ! colcon --log-base log build --base-paths ros2_ws/src --symlink-install \
      --event-handlers console_direct- console_cohesion- status- ${skip_args[@]+"${skip_args[@]}"} \
      --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$venv/bin/python" \
      > log/colcon-build.out 2>&1; then
    grep -v 'local_setup' log/colcon-build.out >&2 || true
    echo "setup: colcon build failed (log/colcon-build.out, log/latest_build)" >&2
    exit 1
  fi
  grep -E '^Summary' log/colcon-build.out || true
  for dir in ros2_ws/src/*/; do
    pkg=$(basename "$dir")
    [ -d "build/$pkg" ] || continue
    (cd "$dir" && ls -1 msg srv action 2>/dev/null || true) > "build/$pkg/.interface-files"
  done
  touch "$build_stamp"
fi
echo "setup: ready (source scripts/env.sh to use the workspace in a shell)"
