#!/usr/bin/env bash
# bench/data_parallel_memory.sh [N] [RANKS] [nrrd|nifti|vdb|dicom]: what a data-parallel render saves in memory. An
# N^3 float32 procedural volume (gyroid_ball; N = 1024: 4 GiB) — or with `nrrd`, an N^3 uint16
# gyroid written as a NRRD of one file per slice (N = 1024: 2 GiB; python3-numpy), with `nifti` as
# one NIfTI-1 file of int16 samples scaled by scl_slope (2 GiB in the file, float32 in memory: 4 GiB;
# python3-nibabel), with `vdb` as an OpenVDB fog volume with every voxel active (float32; written by
# build/bench/make_vdb_sphere --gyroid), with `dicom` as one multi-frame DICOM file of uint16 samples
# (uncompressed; python3-pydicom writes it; GDCM reads it in a child process) — rendered by one process and by
# RANKS ranks with --data-parallel (mpirun, oversubscribed if the machine has fewer cores); prints
# each process's peak resident memory (GNU time), the process's own base (the same render of an
# 8^3 volume), each rank's share of the single process's peak beyond that base, and whether the
# images are the same bits. Defaults: N 1024, RANKS 4 (minutes, ~6 GiB of memory at the peak).
# ISOTRACE=path runs another build.
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-1024}
ranks=${2:-4}
kind=${3:-procedural}
[[ "$n" =~ ^[0-9]+$ && "$ranks" =~ ^[0-9]+$ && "$n" -ge 16 && "$ranks" -ge 2 ]] ||
  { echo "data_parallel_memory: expected N >= 16 and RANKS >= 2" >&2; exit 2; }
[[ "$kind" == procedural || "$kind" == nrrd || "$kind" == nifti || "$kind" == vdb || "$kind" == dicom ]] ||
  { echo "data_parallel_memory: the third argument is 'nrrd', 'nifti', 'vdb', 'dicom' or nothing" >&2; exit 2; }
isotrace=${ISOTRACE:-build/isotrace}
[ -x "$isotrace" ] || { echo "data_parallel_memory: build first (./run.sh or ./test.sh)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# The field the file kinds below write, slice by slice: a gyroid cut to a ball (its surface at 0),
# sampled at cell centres over [-1, 1]^3.
cat > "$work/gyroid_ball.py" <<'PY'
import numpy as np


def gyroid_ball(n):
    """(k, values of slice k) for k in 0..n-1, float32 n x n (rows y, columns x)."""
    c = (np.arange(n, dtype=np.float32) + 0.5) / n * 2 - 1
    y, x = np.meshgrid(c, c, indexing="ij")
    s = 3 * np.pi
    for k in range(n):
        z = c[k]
        g = np.sin(s * x) * np.cos(s * y) + np.sin(s * y) * np.cos(s * z) + np.sin(s * z) * np.cos(s * x)
        yield k, np.maximum(g, np.sqrt(x * x + y * y + z * z) - 0.9)
PY
# An N^3 uint16 gyroid ball as a NRRD with one file per slice (the samples 0..65535, the surface at 32768).
writeNrrd() {  # RESOLUTION FOLDER
  mkdir -p "$2"
  /usr/bin/python3 - "$1" "$2" "$work" <<'PY'
import sys, numpy as np
sys.path.insert(0, sys.argv[3])
from gyroid_ball import gyroid_ball
n, folder = int(sys.argv[1]), sys.argv[2]
for k, v in gyroid_ball(n):
    np.clip(32768 + v * 20000, 0, 65535).astype("<u2").tofile("%s/slice.%04d" % (folder, k))
open(folder + "/field.nhdr", "w").write(
    "NRRD0004\ndimension: 3\ntype: ushort\nsizes: %d %d %d\nendian: little\nencoding: raw\n"
    "data file: slice.%%04d 0 %d 1\n" % (n, n, n, n - 1))
PY
}
# An N^3 gyroid ball as one NIfTI-1 file: int16 samples, scaled by scl_slope 0.5, scl_inter -100
# (the surface at -100).
writeNifti() {  # RESOLUTION FOLDER
  mkdir -p "$2"
  /usr/bin/python3 - "$1" "$2" "$work" <<'PY'
import sys, numpy as np, nibabel as nib
sys.path.insert(0, sys.argv[3])
from gyroid_ball import gyroid_ball
n, folder = int(sys.argv[1]), sys.argv[2]
h = nib.Nifti1Header()
h.set_data_shape((n, n, n))
h.set_data_dtype(np.int16)
h.set_slope_inter(0.5, -100)
h["vox_offset"] = 352
with open(folder + "/field.nii", "wb") as f:
    f.write(h.binaryblock + b"\0" * 4)
    for k, v in gyroid_ball(n):
        f.write(np.clip(v * 16000, -32768, 32767).astype("<i2").tobytes())
PY
}
# An N^3 uint16 gyroid ball as one multi-frame DICOM file (Multi-frame Grayscale Word Secondary
# Capture, explicit VR little endian), the surface at 32768.
writeDicom() {  # RESOLUTION FOLDER
  mkdir -p "$2"
  /usr/bin/python3 - "$1" "$2" "$work" <<'PY'
import sys, numpy as np
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid
sys.path.insert(0, sys.argv[3])
from gyroid_ball import gyroid_ball
n, folder = int(sys.argv[1]), sys.argv[2]
frames = [np.clip(32768 + v * 20000, 0, 65535).astype("<u2").tobytes() for k, v in gyroid_ball(n)]
meta = FileMetaDataset()
meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.7.3"
meta.MediaStorageSOPInstanceUID = generate_uid()
meta.TransferSyntaxUID = ExplicitVRLittleEndian
ds = Dataset()
ds.file_meta = meta
ds.is_little_endian, ds.is_implicit_VR = True, False
ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID
ds.StudyInstanceUID, ds.SeriesInstanceUID = generate_uid(), generate_uid()
ds.Modality = "OT"
ds.Rows = ds.Columns = n
ds.NumberOfFrames = n
ds.SamplesPerPixel = 1
ds.PhotometricInterpretation = "MONOCHROME2"
ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
ds.PixelSpacing = [1, 1]
ds.SpacingBetweenSlices = 1
ds.ImagePositionPatient = [0, 0, 0]
ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
ds.PixelData = b"".join(frames)
ds.save_as(folder + "/field.dcm", write_like_original=False)
PY
}
scene() {  # RESOLUTION
  if [ "$kind" = vdb ]; then
    [ -f "$work/f$1.vdb" ] || "$(dirname "$isotrace")/bench/make_vdb_sphere" --gyroid "$1" "$work/f$1.vdb" > /dev/null
    volume="\"file\": \"$work/f$1.vdb\""
    iso=0
  elif [ "$kind" = dicom ]; then
    [ -f "$work/f$1/field.dcm" ] || writeDicom "$1" "$work/f$1"
    volume="\"file\": \"$work/f$1/field.dcm\""
    iso=32768
  elif [ "$kind" = nifti ]; then
    [ -f "$work/f$1/field.nii" ] || writeNifti "$1" "$work/f$1"
    volume="\"file\": \"$work/f$1/field.nii\""
    iso=-100
  elif [ "$kind" = nrrd ]; then
    [ -f "$work/f$1/field.nhdr" ] || writeNrrd "$1" "$work/f$1"
    volume="\"file\": \"$work/f$1/field.nhdr\""
    iso=32768
  else
    volume="\"procedural\": { \"field\": \"gyroid_ball\", \"resolution\": [$1, $1, $1] }"
    iso=0
  fi
  cat <<JSON
{ "film": { "width": 96, "height": 72 }, "integrator": { "type": "path", "spp": 2, "max_depth": 3 },
  "volumes": [ { $volume,
                 "isosurfaces": [ { "value": $iso, "inside": "below", "material": "red" } ] } ],
  "materials": { "red": { "type": "diffuse", "color": [0.8, 0.3, 0.2] } },
  "lights": [ { "type": "directional", "direction": [0.4, -1, 0.5], "irradiance": 2.5 },
              { "type": "environment", "radiance": 0.3 } ] }
JSON
}
scene "$n" > "$work/big.json"
scene 8 > "$work/small.json"
peak() { sed -n 's/^peak_kib=//p' "$1" | sort -n | tail -n "${2:-1}"; }
/usr/bin/time -f "peak_kib=%M" "$isotrace" render "$work/small.json" --quiet -o "$work/small.exr" > /dev/null 2> "$work/base.txt"
/usr/bin/time -f "peak_kib=%M" "$isotrace" render "$work/big.json" --quiet --threads 2 -o "$work/one.exr" > /dev/null 2> "$work/one.txt"
mpirun --allow-run-as-root --oversubscribe -np "$ranks" /usr/bin/time -f "peak_kib=%M" "$isotrace" render "$work/big.json" \
  --data-parallel --quiet --threads 1 -o "$work/many.exr" --stats "$work/many.json" > /dev/null 2> "$work/many.txt"
base=$(peak "$work/base.txt")
one=$(peak "$work/one.txt")
same=no
oiiotool --fail 0 --failpercent 0 "$work/one.exr" "$work/many.exr" --diff > /dev/null 2>&1 && same=yes
if [ "$kind" = vdb ]; then
  echo "volume ${n}^3 float32, an OpenVDB fog volume with every voxel active, $ranks ranks; peak resident memory, MiB:"
elif [ "$kind" = dicom ]; then
  echo "volume ${n}^3 uint16 held as float32, one multi-frame DICOM file ($(( n * n * n * 2 / 1048576 )) MiB), $ranks ranks; peak resident memory, MiB:"
elif [ "$kind" = nifti ]; then
  echo "volume ${n}^3 int16 scaled to float32, one NIfTI-1 file ($(( n * n * n * 2 / 1048576 )) MiB), $ranks ranks; peak resident memory, MiB:"
elif [ "$kind" = nrrd ]; then
  echo "volume ${n}^3 uint16, a NRRD of $n slice files ($(( n * n * n * 2 / 1048576 )) MiB), $ranks ranks; peak resident memory, MiB:"
else
  echo "volume ${n}^3 float32 ($(( n * n * n * 4 / 1048576 )) MiB), $ranks ranks; peak resident memory, MiB:"
fi
echo "| process | peak | beyond the base | share of one process's beyond the base |"
echo "|---|---|---|---|"
echo "| base (8^3 volume) | $(( base / 1024 )) | | |"
echo "| one process | $(( one / 1024 )) | $(( (one - base) / 1024 )) | 1 |"

for p in $(sed -n 's/^peak_kib=//p' "$work/many.txt"); do
  echo "| a rank | $(( p / 1024 )) | $(( (p - base) / 1024 )) | $(awk -v p="$p" -v b="$base" -v o="$one" 'BEGIN { printf "%.3f", (p - b) / (o - b) }') |"

done
echo "same image bits: $same"
