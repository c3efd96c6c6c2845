#!/usr/bin/env bash
# Idempotent set-up of the rwpend workspace (called by `make setup`).
#   1. .venv with Python 3.11 and the pinned wheels of requirements.txt
#   2. rwpend_msgs built with cmake (ament_cmake + rosidl) and installed into the venv prefix,
#      like the ROS wheels themselves, so no sourcing is ever needed
#   3. the ament_python packages installed editable into the venv
# With --browser (make test, make test-browser) also Debian's chromium and chromium-driver, which
# the console's page tests drive.
# Each step is skipped when its inputs did not change (stamp files in .venv/).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=$ROOT/.venv
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
PYPKGS="rwpend_model rwpend_ros rwpend_sim rwpend_estimation rwpend_control rwpend_driver rwpend_bag rwpend_loop rwpend_bringup rwpend_lab rwpend_ident rwpend_console rwpend_sweep rwpend_bench"

# --firmware (make firmware): only the cross compiler of the rig's reference firmware (firmware/),
# Debian's gcc-arm-none-eabi and its newlib. Nothing else of the set-up below.
firmware_tools() {
  local need=""
  command -v arm-none-eabi-gcc >/dev/null 2>&1 || need="$need gcc-arm-none-eabi"
  dpkg-query -W -f='${Status}' libnewlib-arm-none-eabi 2>/dev/null | grep -q "install ok installed" \
    || need="$need libnewlib-arm-none-eabi"
  if [ -n "$need" ]; then
    echo "setup: installing the firmware's cross compiler:$need"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO=sudo; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq $need
  fi
}
if [ "${1:-}" = --firmware ]; then
  firmware_tools
  exit 0
fi

# --cluster (make setup-cluster, make test): also the Dask extra of ./rwpend sweep --scheduler
# (requirements-cluster.txt)
cluster=0
for arg in "$@"; do if [ "$arg" = --cluster ]; then cluster=1; fi; done

need_apt=""
if [ "${1:-}" = --browser ]; then   # the console's page tests (make test): Debian's chromium + its driver
  command -v chromium >/dev/null 2>&1 || need_apt="$need_apt chromium"
  command -v chromedriver >/dev/null 2>&1 || need_apt="$need_apt chromium-driver"
fi
command -v cmake >/dev/null 2>&1 || need_apt="$need_apt cmake"
command -v g++ >/dev/null 2>&1 || need_apt="$need_apt g++"
command -v make >/dev/null 2>&1 || need_apt="$need_apt make"
"$PY" -c "import ensurepip, venv" >/dev/null 2>&1 || need_apt="$need_apt python3-venv"
if [ -n "$need_apt" ]; then
  echo "setup: installing system packages:$need_apt"
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO=sudo; fi
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq $need_apt
fi

"$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), "rwpend needs Python 3.11 (the ROS 2 Jazzy wheels are cp311)"'

stamp_ok() {  # stamp_ok STAMP FILE... : stamp newer than every input?
  local s=$1; shift
  [ -f "$s" ] || return 1
  [ -z "$(find "$@" -newer "$s" -print -quit 2>/dev/null)" ]
}

SECONDS=0
if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PY" -m venv "$VENV"
fi
if ! stamp_ok "$VENV/.stamp-deps" requirements.txt tools/setup.sh; then
  echo "setup: installing pinned wheels (requirements.txt)"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --upgrade "pip==24.3.1"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements.txt
  touch "$VENV/.stamp-deps"
fi

export VIRTUAL_ENV=$VENV PATH=$VENV/bin:$PATH AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV
if ! stamp_ok "$VENV/.stamp-msgs" rwpend_msgs "$VENV/.stamp-deps"; then
  echo "setup: building rwpend_msgs (cmake, ament_cmake + rosidl) into the venv"
  mkdir -p build
  if ! { cmake -S rwpend_msgs -B build/rwpend_msgs -DCMAKE_INSTALL_PREFIX="$VENV" \
           -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
         && cmake --build build/rwpend_msgs -j"$(nproc)" \
         && cmake --install build/rwpend_msgs; } > build/rwpend_msgs.log 2>&1; then
    tail -40 build/rwpend_msgs.log
    echo "setup: rwpend_msgs build FAILED (full log: build/rwpend_msgs.log)" >&2
    exit 1
  fi
  touch "$VENV/.stamp-msgs"
fi

setup_files=""
for p in $PYPKGS; do [ -f "$p/setup.py" ] && setup_files="$setup_files $p/setup.py $p/package.xml"; done
if ! stamp_ok "$VENV/.stamp-py" $setup_files "$VENV/.stamp-deps"; then
  echo "setup: installing the Python packages (editable)"
  args=""
  for p in $PYPKGS; do [ -f "$p/setup.py" ] && args="$args -e ./$p"; done
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation --config-settings editable_mode=compat $args
  touch "$VENV/.stamp-py"
fi
if [ "$cluster" = 1 ] && ! stamp_ok "$VENV/.stamp-cluster" requirements-cluster.txt "$VENV/.stamp-deps"; then
  echo "setup: installing the cluster extra (requirements-cluster.txt: dask, distributed)"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements-cluster.txt
  touch "$VENV/.stamp-cluster"
fi
"$VENV/bin/python" -c "import rclpy, rwpend_msgs.msg" \
  || { echo "setup: the environment does not import rclpy/rwpend_msgs" >&2; exit 1; }
echo "setup: ready (${SECONDS} s)"
