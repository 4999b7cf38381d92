#!/usr/bin/env bash
# Set up the pip route: a virtual environment at the repository root with ROS 2 Jazzy from
# PyPI wheels, the interface package okid_msgs built into it, and okid_ros installed editable.
# Afterwards, with nothing sourced:
#   .venv/bin/okid-ros --help
#   .venv/bin/python -m pytest
#   .venv/bin/python -c "import rclpy, okid_msgs.msg"
#
# Idempotent: each stage records a hash of its inputs under $VENV/.okid-stamps and is skipped
# when they have not changed, so a second run takes about a second. Safe to run concurrently
# (one run at a time holds a lock).
#
# Environment:
#   PYTHON  interpreter for the venv; must be CPython 3.11 (the wheels are cp311).
#           Default: Debian's /usr/bin/python3.11, else python3.11 on PATH.
#   VENV    where to create the venv (default: <repo>/.venv).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${VENV:-$ROOT/.venv}"
case "$VENV" in /*) ;; *) VENV="$ROOT/$VENV" ;; esac
STAMPS="$VENV/.okid-stamps"
REQ="$ROOT/requirements"
cd "$ROOT"  # hash_of and the globs below name files relative to the repository root

log() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }

# One setup at a time: `make test` of several shells would otherwise race on the same venv.
exec 9<"${BASH_SOURCE[0]}"
flock 9

# --- system packages ----------------------------------------------------------------------

APT_PACKAGES=()
need_apt() { APT_PACKAGES+=("$@"); }

install_apt_packages() {
    [ "${#APT_PACKAGES[@]}" -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null; then
        die "missing system packages: ${APT_PACKAGES[*]}
  install them (Debian/Ubuntu: sudo apt-get install -y ${APT_PACKAGES[*]}) and run again"
    fi
    log "installing system packages: ${APT_PACKAGES[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${APT_PACKAGES[@]}" >/dev/null
    APT_PACKAGES=()
}

choose_python() {
    if [ -n "${PYTHON:-}" ]; then
        command -v "$PYTHON" >/dev/null || die "PYTHON=$PYTHON not found"
        PYTHON="$(command -v "$PYTHON")"
    elif [ -x /usr/bin/python3.11 ]; then
        # Debian's interpreter: apt can supply its venv module and headers on any Debian 12.
        PYTHON=/usr/bin/python3.11
    elif command -v python3.11 >/dev/null; then
        PYTHON="$(command -v python3.11)"
    else
        need_apt python3 python3-venv python3-dev
        install_apt_packages
        PYTHON=/usr/bin/python3.11
    fi
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' ||
        die "$PYTHON is not CPython 3.11; the ROS 2 Jazzy wheels are cp311 (set PYTHON=...)"
}

python_is_debian() { case "$PYTHON" in /usr/bin/*) return 0 ;; *) return 1 ;; esac; }

check_system() {
    command -v cmake >/dev/null || need_apt cmake
    command -v make >/dev/null || need_apt make
    command -v g++ >/dev/null || need_apt g++
    # Debian splits venv (ensurepip) and the C headers out of the interpreter's package;
    # rosidl_generator_py compiles a C extension per message package.
    local missing=()
    "$PYTHON" -c 'import ensurepip' 2>/dev/null || missing+=(python3-venv)
    "$PYTHON" -c 'import os, sys, sysconfig
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' ||
        missing+=(python3-dev)
    if [ "${#missing[@]}" -gt 0 ]; then
        python_is_debian || die "$PYTHON lacks ${missing[*]} (venv module / C headers);
  use Debian's python (PYTHON=/usr/bin/python3.11) or an interpreter that has them"
        need_apt "${missing[@]}"
    fi
    install_apt_packages
}

# --- stages -------------------------------------------------------------------------------

# hash_of FILE...: one hash over the names and contents of the given files.
hash_of() { sha256sum "$@" | sha256sum | cut -c1-64; }
stage_done() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark_done() { mkdir -p "$STAMPS" && printf '%s\n' "$2" >"$STAMPS/$1"; }

make_venv() {
    if [ -x "$VENV/bin/python" ] &&
        "$VENV/bin/python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null &&
        "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
        return 0
    fi
    log "creating $VENV with $PYTHON ($("$PYTHON" --version 2>&1))"
    rm -rf "$VENV"
    "$PYTHON" -m venv "$VENV"
}

install_wheels() {
    local h
    h="$(hash_of requirements/bootstrap.txt requirements/ros-jazzy.txt requirements/python.txt \
        requirements/test.txt requirements/lock.txt)"
    stage_done wheels "$h" && return 0
    log "installing pinned wheels from PyPI (requirements/*.txt)"
    # --no-compile: pip would write the bytecode of every module of every wheel, their tests
    # included (38 s of CPU, more than the rest of the install); compile_imported writes that of
    # what okid_ros imports, Python the rest at first import.
    "$VENV/bin/python" -m pip install -q --no-compile -r "$REQ/bootstrap.txt"
    # Runtime (python.txt) and test/benchmark (test.txt) dependencies: `make test` needs both.
    "$VENV/bin/python" -m pip install -q --no-compile -r "$REQ/ros-jazzy.txt" -r "$REQ/python.txt" \
        -r "$REQ/test.txt" -c "$REQ/lock.txt"
    fix_cmake_paths
    mark_done wheels "$h"
}

# The exported CMake targets of the message wheels carry include paths of the machine they
# were built on; CMake refuses them ("Imported target ... includes non-existent path").
# Point them at this interpreter's headers and this numpy. Only files inside the venv change.
fix_cmake_paths() {
    local py_inc np_inc files
    py_inc="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
    np_inc="$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')"
    files="$(grep -l -e /opt/python/cp311-cp311/include/python3.11 \
        -e /opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include \
        "$VENV"/share/*/cmake/*.cmake || true)"
    [ -z "$files" ] && return 0
    log "rewriting build-machine include paths in $(echo "$files" | wc -l) CMake files"
    # shellcheck disable=SC2086 # one file name a line, no spaces inside the venv's share/
    sed -i -e "s|/opt/python/cp311-cp311/include/python3.11|$py_inc|g" \
        -e "s|/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include|$np_inc|g" \
        $files
}

build_msgs() {
    local h
    # Rebuilt when the messages or the ROS wheels they are generated with change.
    h="$(hash_of requirements/ros-jazzy.txt msg_defs/package.xml msg_defs/CMakeLists.txt msg_defs/msg/*.msg)"
    stage_done msgs "$h" && return 0
    log "building okid_msgs with colcon into $VENV"
    # Merge-install into the venv prefix: the libraries land in $VENV/lib (on the library path
    # the wheels' start-up hook sets) and the Python package in site-packages, so nothing has
    # to be sourced. Build files and logs stay inside the venv. Always a clean build (~15 s):
    # an incremental one can keep a stale CMake cache (another checkout, a renamed message).
    rm -rf "$VENV/.build/colcon"
    (
        export CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV"
        "$VENV/bin/colcon" --log-base "$VENV/.build/log" build \
            --base-paths msg_defs \
            --build-base "$VENV/.build/colcon" \
            --install-base "$VENV" --merge-install \
            --event-handlers console_stderr+ status- \
            --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF
    ) >"$VENV/.build-msgs.log" 2>&1 || {
        tail -n 40 "$VENV/.build-msgs.log" >&2
        die "building okid_msgs failed; full log: $VENV/.build-msgs.log"
    }
    "$VENV/bin/python" -c 'import okid_msgs.msg' ||
        die "okid_msgs built but does not import; see $VENV/.build-msgs.log"
    mark_done msgs "$h"
}

install_okid_ros() {
    local h
    h="$(hash_of setup.py setup.cfg package.xml)"
    stage_done okid_ros "$h" && return 0
    log "installing okid_ros (editable)"
    # No build isolation: use the pinned setuptools of the venv, no extra download. The output
    # (setuptools' warnings about editable installs) goes to a log, shown on failure.
    "$VENV/bin/python" -m pip install --no-deps --no-build-isolation -e "$ROOT" \
        >"$VENV/.install-okid_ros.log" 2>&1 || {
        tail -n 40 "$VENV/.install-okid_ros.log" >&2
        die "installing okid_ros failed; full log: $VENV/.install-okid_ros.log"
    }
    mark_done okid_ros "$h"
}

# The bytecode of every module of okid_ros and of what they import (rclpy, scipy, matplotlib, ...),
# written even where the environment says not to (PYTHONDONTWRITEBYTECODE, as on CI machines):
# else each node and command would compile them again at every start.
compile_imported() {
    local h
    h="$(cat "$STAMPS/wheels" "$STAMPS/msgs" "$STAMPS/okid_ros" | sha256sum | cut -c1-64)"
    stage_done bytecode "$h" && return 0
    log "writing the bytecode of okid_ros and of the modules it imports"
    env PYTHONDONTWRITEBYTECODE= "$VENV/bin/python" -c 'import importlib, pkgutil, okid_ros
for module in pkgutil.walk_packages(okid_ros.__path__, "okid_ros."):
    importlib.import_module(module.name)' || die "okid_ros's modules do not import; see the error above"
    mark_done bytecode "$h"
}

check_result() {
    env -u AMENT_PREFIX_PATH -u CMAKE_PREFIX_PATH \
        "$VENV/bin/python" -c 'import rclpy, okid_msgs.msg, okid_ros' ||
        die "the venv does not import rclpy, okid_msgs.msg and okid_ros"
    "$VENV/bin/okid-ros" --help >/dev/null || die "$VENV/bin/okid-ros --help failed"
}

main() {
    choose_python
    check_system
    make_venv
    install_wheels
    build_msgs
    install_okid_ros
    compile_imported
    check_result
    log "ready: $VENV"
}

main "$@"
