# Source this file (bash) for the environment the `ros2` feature builds and runs in, with the prefix
# launch/ros2/setup.sh prepared: `source launch/ros2/env.sh [prefix]`.
_gf_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
# Absolute: cargo runs r2r's build scripts in other directories.
_gf_prefix="$(cd "${1:-$_gf_root/target/ros2}" && pwd)"
_gf_venv="$_gf_prefix/venv"
_gf_site="$_gf_venv/lib/python3.11/site-packages"

export ROS_DISTRO=jazzy
export AMENT_PREFIX_PATH="$_gf_prefix/msgs:$_gf_venv"
export CMAKE_PREFIX_PATH="$AMENT_PREFIX_PATH"
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
# Shared-memory segments that hold camera frames (see the file for why and the measurement).
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_gf_root/launch/ros2/fastdds.xml}"
# Discovery stays on this machine unless the user widens it.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# r2r generates Rust types for every package in the prefix unless filtered: only what the node uses.
export IDL_PACKAGE_FILTER="std_msgs;builtin_interfaces;geometry_msgs;sensor_msgs;visualization_msgs;tf2_msgs;vision_msgs;groupforward_msgs;service_msgs;unique_identifier_msgs;action_msgs"
# bindgen uses the libclang of the PyPI wheel; that libclang ships no C headers (stdbool.h), so
# the compiler's own are named.
export LIBCLANG_PATH="$_gf_site/clang/native"
_gf_cc_include="$(gcc -print-file-name=include 2>/dev/null || true)"
export BINDGEN_EXTRA_CLANG_ARGS="${_gf_cc_include:+-I$_gf_cc_include}"
# The wheels' shared libraries: the prefix's lib folders, and the vendored ones auditwheel put
# beside each package (site-packages/*.libs).
_gf_libs="$_gf_prefix/msgs/lib:$_gf_venv/lib"
for _gf_dir in "$_gf_site"/*.libs; do
  [[ -d "$_gf_dir" ]] && _gf_libs="$_gf_libs:$_gf_dir"
done
export LD_LIBRARY_PATH="$_gf_libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export PYTHONPATH="$_gf_prefix/msgs/lib/python3.11/site-packages${PYTHONPATH:+:$PYTHONPATH}"
export PATH="$_gf_venv/bin:$PATH"
# libpython, which launch/ros2/groupforward preloads (see there why).
GF_ROS2_LIBPYTHON="$("$_gf_venv/bin/python" -c 'import sysconfig as s; print(s.get_config_var("LIBDIR") + "/" + s.get_config_var("LDLIBRARY"))' 2>/dev/null || true)"
export GF_ROS2_LIBPYTHON
unset _gf_root _gf_prefix _gf_venv _gf_site _gf_cc_include _gf_libs _gf_dir
