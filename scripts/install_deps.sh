#!/usr/bin/env bash
# Installs the Debian packages this package builds, runs and tests with. Idempotent.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
export DEBIAN_FRONTEND=noninteractive

packages=(
  build-essential cmake catkin python3-catkin-pkg catkin-lint
  ros-core-dev libroscpp-dev librosbag-dev
  libtf2-ros-dev libtf2-dev libtf2-msgs-dev libgeometry-msgs-dev
  libvisualization-msgs-dev libsensor-msgs-dev python3-sensor-msgs libros-rosgraph-msgs-dev
  libshape-msgs-dev python3-shape-msgs
  libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure libstd-srvs-dev libstd-msgs-dev libdiagnostic-updater-dev
  libdiagnostic-msgs-dev libinteractive-markers-dev librostest-dev python3-rostest python3-roslaunch
  libactionlib-dev libactionlib-msgs-dev ros-actionlib-msgs python3-actionlib python3-actionlib-msgs
  libeigen3-dev libspectra-dev libsuitesparse-dev libopenblas-dev libgtest-dev googletest libbenchmark-dev libyaml-cpp-dev
  python3-rosservice python3-rostopic python3-rosbag python3-rosnode python3-rosparam rosbash
  python3-std-srvs python3-std-msgs python3-visualization-msgs python3-geometry-msgs
  python3-tf2-msgs python3-tf2-ros python3-diagnostic-msgs python3-rosgraph-msgs python3-genmsg python3-gencpp python3-genpy
  python3-matplotlib python3-numpy
  python3-rospy python3-roslib python3-rosgraph python3-rosunit
)
# The viewer, only for the main job with a display (scripts/run.sh sets MODAL_VIEWER=1) and the
# screenshot under Xvfb: CI and the tests do not need it.
if [ "${MODAL_VIEWER:-0}" = "1" ]; then
  packages+=(rviz xvfb xauth x11-utils imagemagick)
fi
# Bullet, only for the optional peer benchmark benchmark/bullet_peer (docs/benchmarks.md): the build
# and the tests do not need it.
if [ "${MODAL_BULLET:-0}" = "1" ]; then
  packages+=(libbullet-dev pkg-config)
fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  ${SUDO:-} apt-get update -q
  ${SUDO:-} apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
