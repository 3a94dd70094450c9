#!/usr/bin/env bash
# Prints, one a line, the stand-in packages of ros2_ws/src (package.xml exports
# <katana_stand_in/>: local builds of standard interfaces missing from PyPI) that an installed
# prefix already provides. The build skips those (colcon --packages-skip), so on a full ROS
# install the real package wins and its type hashes are the ones the graph speaks.
#
# Prefixes searched: the venv (a ROS wheel of the package may be installed there one day) and
# every entry of AMENT_PREFIX_PATH (a sourced /opt/ros/jazzy). A prefix whose copy of the
# package is itself a stand-in (this or another checkout's install/) does not count.
# Usage: installed_stand_ins.sh [WORKSPACE_ROOT] (default: this script's checkout).
set -euo pipefail
root=${1:-$(cd "$(dirname "$0")/.." && pwd)}
prefixes=${VIRTUAL_ENV:-$root/.venv}:${AMENT_PREFIX_PATH:-}

for xml in "$root"/ros2_ws/src/*/package.xml; do
  grep -q '<katana_stand_in */>' "$xml" || continue
  pkg=$(basename "$(dirname "$xml")")
  IFS=: read -r -a dirs <<< "$prefixes"
  for prefix in "${dirs[@]}"; do
    [ -n "$prefix" ] || continue
    [ -e "$prefix/share/ament_index/resource_index/packages/$pkg" ] || continue
    grep -q '<katana_stand_in */>' "$prefix/share/$pkg/package.xml" 2>/dev/null && continue
    echo "$pkg"
    break
  done
done
