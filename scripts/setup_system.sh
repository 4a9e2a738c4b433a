#!/usr/bin/env bash
# Install the system libraries MuJoCo needs for offscreen rendering, if they are missing.
# EGL through Mesa (llvmpipe) renders on a machine without GPU; OSMesa is the fallback.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' && ldconfig -p | grep -q 'libGL.so.1'; then
  echo "GL libraries present"
  exit 0
fi
SUDO=""
[ "$(id -u)" = 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends libegl1 libgl1 libgles2 libegl-mesa0 libgl1-mesa-dri libosmesa6 >/dev/null
echo "installed GL libraries"
