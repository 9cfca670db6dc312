#!/usr/bin/env bash
# A CPU-only libtorch 2.9.0 (what burn 0.22's `tch` backend links) assembled from PyPI wheels, for
# `make train BACKEND=tch`. PyPI has no CPU build of torch 2.9.0 for Linux, and its wheel depends
# on 6.8 GB of CUDA wheels; but libtorch_cpu.so itself needs only libcudart and libcupti (two
# small wheels, loaded lazily, no GPU needed). So: download the three wheels without their
# dependencies, keep the headers and the CPU libraries (≈ 490 MB), and replace libtorch.so (which
# would pull in libtorch_cuda.so) by a stub that links libtorch_cpu.so. torch-sys links
# torch_cuda only when lib/libtorch_cuda.so exists, so it links this tree as a CPU libtorch.
#
#   scripts/setup_libtorch_cpu.sh [DEST]     # default build/libtorch-cpu; prints DEST
#
# Idempotent; builds into DEST.tmp and renames, so an interrupted run leaves no half tree.
# Needs: pip (from PIP, default .venv/bin/pip), unzip, a C compiler.
set -euo pipefail

version=2.9.0
dest=${1:-build/libtorch-cpu}
wheels=${WHEELS:-build/wheels}
pip=${PIP:-.venv/bin/pip}

if [[ -f "$dest/build-version" && "$(cat "$dest/build-version")" == "$version" && -f "$dest/lib/libtorch.so" ]]; then
    echo "$dest"
    exit 0
fi
for tool in unzip cc; do
    command -v "$tool" >/dev/null || { echo "setup_libtorch_cpu: '$tool' is not installed; install it (apt-get install $tool) and rerun" >&2; exit 1; }
done

mkdir -p "$wheels"
"$pip" download --quiet --no-deps --dest "$wheels" \
    "torch==$version" nvidia-cuda-runtime-cu12==12.8.90 nvidia-cuda-cupti-cu12==12.8.90 >&2

staging="$dest.tmp"
rm -rf "$staging"
mkdir -p "$staging/lib" "$staging/unpacked"
unzip -q "$wheels"/torch-"$version"-*.whl 'torch/include/*' torch/lib/libtorch_cpu.so \
    torch/lib/libc10.so torch/lib/libgomp.so.1 -d "$staging/unpacked"
unzip -q -j "$wheels"/nvidia_cuda_runtime_cu12-12.8.90-*.whl nvidia/cuda_runtime/lib/libcudart.so.12 -d "$staging/lib"
unzip -q -j "$wheels"/nvidia_cuda_cupti_cu12-12.8.90-*.whl nvidia/cuda_cupti/lib/libcupti.so.12 -d "$staging/lib"
mv "$staging/unpacked/torch/include" "$staging/include"
mv "$staging/unpacked/torch/lib/"* "$staging/lib/"
rm -rf "$staging/unpacked"

# libtorch.so of a CPU build is itself only a shim over libtorch_cpu.so.
echo 'void boxpose_libtorch_cpu_stub(void) {}' >"$staging/stub.c"
cc -shared -fPIC "$staging/stub.c" -o "$staging/lib/libtorch.so" -Wl,-soname,libtorch.so \
    -Wl,--no-as-needed -L"$staging/lib" -ltorch_cpu -Wl,-rpath,'$ORIGIN'
rm "$staging/stub.c"
echo "$version" >"$staging/build-version"

rm -rf "$dest"
mv "$staging" "$dest"
echo "$dest"
