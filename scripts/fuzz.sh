#!/usr/bin/env bash
# scripts/fuzz.sh [SECONDS] [TARGET...]: builds the libFuzzer targets of fuzz/ with clang-14
# (AddressSanitizer and UndefinedBehaviorSanitizer on) in build-fuzz/ and runs each for SECONDS
# (default 60) from a corpus seeded with the repository's real files. Prints executions and
# findings per target; a crash leaves its input in build-fuzz/crashes/TARGET/ (make it a
# regression test). Not part of ./test.sh: it takes minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
shift || true
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(scene volume gltf image)

ISOTRACE_SKIP_BUILD=1 ./scripts/setup.sh
missing=()
for p in clang-14 libfuzzer-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

CC=clang-14 CXX=clang++-14 cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=Release -DISOTRACE_FUZZ=ON >/dev/null
cmake --build build-fuzz -j2 --target $(printf '%s_fuzzer ' "${targets[@]}") -- --no-print-directory 2>&1 |
  grep -Ev '^\[ *[0-9]+%\]|^Consolidate|^Scanning' || true

# Seeds: the real files the readers are meant for (the first byte of each seed picks the
# format in the target; see fuzz/*_fuzzer.cpp).
seed() {  # seed TARGET PREFIX_BYTE FILE
  local dir=build-fuzz/corpus/$1
  mkdir -p "$dir"
  { printf "\\x$(printf %02x "$2")"; head -c 65536 "$3"; } > "$dir/seed-$(basename "$3")-$2"
}
data=examples/data
for f in examples/*.json bench/scenes/*.json bench/noise/*.json; do
  mkdir -p build-fuzz/corpus/scene && cp "$f" "build-fuzz/corpus/scene/seed-$(basename "$f")"
done
seed volume 0 <(printf 'NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nencoding: ascii\n\n1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24\n')
seed volume 1 $data/volumes/headsq/quarter.nhdr
seed volume 2 $data/volumes/HeadMRVolume.mhd
seed volume 3 $data/volumes/ironProt.vtk
seed volume 4 <(head -c 64 $data/volumes/bucky_32x32x32_uint8.raw)
seed volume 5 <(head -c 256 $data/volumes/bucky_32x32x32_uint8.raw | gzip)
seed volume 7 <(head -c 48 $data/volumes/neghip_64x64x64_uint8.raw)
nibabel=/usr/lib/python3/dist-packages/nibabel/tests/data  # python3-nibabel's test files
seed volume 8 <(gunzip -c $nibabel/standard.nii.gz)
seed volume 8 $nibabel/reoriented_anat_moved.nii
seed volume 9 $nibabel/example_nifti2.nii.gz
seed gltf 0 $data/meshes/BoxTextured/BoxTextured.gltf
seed gltf 1 $data/meshes/Box.glb
seed gltf 2 $data/meshes/cornell/cornell_box.obj
seed image 0 $data/meshes/BoxTextured/CesiumLogoFlat.png

mkdir -p build-fuzz/crashes
status=0
for t in "${targets[@]}"; do
  mkdir -p build-fuzz/corpus/$t build-fuzz/crashes/$t
  log=build-fuzz/$t.log
  # -rss_limit_mb: the readers' own limits must keep every input far below it. Leaks are not
  # looked for in the image target: OpenImageIO keeps its PNG reader's error strings (a leak
  # of libOpenImageIO, not of isotrace). scripts/lsan.supp names the libraries whose own leaks
  # are not isotrace's (OpenVDB leaks the nodes of a tree whose reading throws).
  leaks=1; [ "$t" = image ] && leaks=0
  if ! ASAN_OPTIONS="detect_leaks=$leaks" LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp" build-fuzz/fuzz/${t}_fuzzer build-fuzz/corpus/$t -max_total_time="$seconds" -rss_limit_mb=2048 \
       -detect_leaks=$leaks -timeout=10 -max_len=65536 -artifact_prefix=build-fuzz/crashes/$t/ \
       -print_final_stats=1 > "$log" 2>&1; then
    status=1
  fi
  runs=$(grep -m1 'stat::number_of_executed_units' "$log" | awk '{print $2}')
  crashes=$(ls build-fuzz/crashes/$t | wc -l)
  printf 'fuzz %-7s %10s executions in %ss, %s findings (log: %s)\n' "$t" "${runs:-?}" "$seconds" "$crashes" "$log"
done
exit $status
