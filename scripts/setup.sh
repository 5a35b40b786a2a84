#!/usr/bin/env bash
# Installs the Debian packages isotrace needs (idempotent; quiet when nothing is missing)
# and configures + builds a Release build in ./build. openimageio-tools is listed because
# Debian 12's OpenImageIO CMake config refers to its binaries and fails without them;
# libopenexr-dev and libpng-dev write EXR and PNG output without OpenImageIO (which only a
# plugin loaded at first use links, scene/image_plugin.h);
# libopenvdb-dev (with libboost-iostreams-dev, which its CMake module needs) builds
# `isotrace mesh` (OpenVDB's volumeToMesh). libnifti2-dev reads NIfTI headers; python3-nibabel
# is there for its test files (real NIfTI-1/2 volumes the tests read), python3-pydicom for its
# DICOM test files; libgdcm-dev reads DICOM, libtinyobjloader-dev OBJ meshes; Open MPI
# (libopenmpi-dev, openmpi-bin: mpirun) renders on many ranks; libcpp-httplib-dev serves
# `isotrace view`, whose page the tests drive in Debian's chromium with chromium-driver and
# python3-selenium (no browser is downloaded); stress-ng loads the machine for
# scripts/soak_tests.sh --loaded; fonts-dejavu-core is the font of `render --colorbar`'s legend;
# GNU time (/usr/bin/time) measures peak memory in bench/data_parallel_memory.sh; ffmpeg (the
# program) encodes `render -o NAME.mp4 / .webm` videos.
# The Python module (python/) builds with pybind11-dev against python3-dev and python3-numpy;
# its tests run under python3-pytest, and its notebook under python3-nbconvert and
# python3-ipykernel. After the build, a .pth file in Debian's python3 site folder
# (/usr/local/lib/python3.X/dist-packages/isotrace.pth) names build/python of this checkout, so
# `import isotrace` works in /usr/bin/python3 from anywhere (the last checkout set up wins;
# delete that file to undo).
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(build-essential cmake pkg-config
          libembree-dev libopenimageio-dev openimageio-tools libopenexr-dev libpng-dev libtbb-dev
          libtinygltf-dev nlohmann-json3-dev libstb-dev
          libcli11-dev libgtest-dev libbenchmark-dev zlib1g-dev
          libopenvdb-dev libboost-iostreams-dev
          libnifti2-dev python3-nibabel libtinyobjloader-dev libgdcm-dev python3-pydicom
          libopenmpi-dev openmpi-bin libcpp-httplib-dev chromium chromium-driver python3-selenium
          stress-ng fonts-dejavu-core time ffmpeg
          pybind11-dev python3-dev python3-numpy python3-pytest python3-nbconvert python3-ipykernel)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "isotrace: installing missing packages: ${missing[*]}" >&2
  sudo_cmd=""
  [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $sudo_cmd apt-get update -qq >/dev/null
  $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if [ "${ISOTRACE_SKIP_BUILD:-0}" != "1" ]; then
  cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
  cmake --build build -j2 -- --no-print-directory 2>&1 | grep -Ev '^\[ *[0-9]+%\]|^Consolidate|^Scanning' || true
  test -x build/isotrace
  # `import isotrace` in Debian's python3 from anywhere: a .pth naming this build's module folder.
  site=$(/usr/bin/python3 -c 'import sys; print("/usr/local/lib/python%d.%d/dist-packages" % sys.version_info[:2])')
  if [ -d build/python/isotrace ]; then
    sudo_cmd=""
    [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
    $sudo_cmd mkdir -p "$site"
    echo "$PWD/build/python" | $sudo_cmd tee "$site/isotrace.pth" >/dev/null
  fi
fi
