#!/usr/bin/env bash
# Training speed of the keypoint network on every backend built here, in one run (`make
# bench-backends`): the bare training step (rust/learn/benches/keypoint_step.rs: forward, loss,
# backward, Adam on random data), then steps per second of a real `boxpose train` on a dataset
# (data loading, augmentation and target rendering included), each against flex, the default,
# and against its own bare step (the throughput issue's goal: within 1.2×).
#
#   scripts/bench_backends.sh [DATASET]      # default datasets/generated/train
#   BACKENDS="flex tch" STEPS=40 FIRST=5 BACKBONES="slim resnet18" scripts/bench_backends.sh
#
# The training runs are of FIRST and FIRST + STEPS steps. With the default FIRST=5 the measured
# steps are the first epoch's, when most frames are read and decoded for the first time; a FIRST
# past the first epoch (e.g. 200 on 400 frames) measures the steady state, frames from the cache.
#
# A backend other than flex is measured when its build exists (target/BACKEND/release/boxpose,
# from `make train BACKEND=…`); tch also needs its libtorch (build/libtorch-cpu).
set -euo pipefail
cd "$(dirname "$0")/.."

dataset=${1:-datasets/generated/train}
backends=${BACKENDS:-flex tch}
steps=${STEPS:-40}
first=${FIRST:-5}
backbones=${BACKBONES:-slim resnet18}
libtorch=$PWD/build/libtorch-cpu
out=$(mktemp -d /tmp/bench-backends.XXXXXX)
trap 'rm -rf "$out"' EXIT

binary_of() { [[ $1 == flex ]] && echo target/release/boxpose || echo "target/$1/release/boxpose"; }
bench_of() { [[ $1 == flex ]] && echo target/release || echo "target/$1/release"; }

echo "keypoint network training, $(nproc) cores; medians of 10 steps after 2 warm-up steps"
printf '%-9s %-8s %14s %12s %10s\n' backbone backend "step (b=8)" "steps/s" "vs flex"
declare -A slim_step_ms
for backbone in $backbones; do
    reference=
    for backend in $backends; do
        bench=$(find "$(bench_of "$backend")/deps" -maxdepth 1 -name 'keypoint_step-*' -type f -executable 2>/dev/null | head -1)
        if [[ -z $bench ]]; then
            printf '%-9s %-8s %14s\n' "$backbone" "$backend" "not built"
            continue
        fi
        json=$(LD_LIBRARY_PATH=$libtorch/lib:${LD_LIBRARY_PATH:-} "$bench" --bench --backbone "$backbone" --backend "$backend" --steps 10 | tail -1)
        ms=$(python3 -c "import json,sys; print(json.loads(sys.argv[1])['train_step_ms'])" "$json")
        reference=${reference:-$ms}
        [[ $backbone == slim ]] && slim_step_ms[$backend]=$ms
        printf '%-9s %-8s %11.0f ms %12.2f %9.2f×\n' "$backbone" "$backend" "$ms" \
            "$(python3 -c "print(1000/$ms)")" "$(python3 -c "print($reference/$ms)")"
    done
done

echo
echo "boxpose train on $dataset (configs/keypoint-slim.toml): seconds per step from two runs, of $first and $first + $steps steps,"
echo "so that start-up and the closing validation cancel; data loading, augmentation and targets included"
printf '%-8s %12s %10s %16s\n' backend "steps/s" "vs flex" "time / bare step"
reference=
for backend in $backends; do
    binary=$(binary_of "$backend")
    if [[ ! -x $binary ]]; then
        printf '%-8s %12s\n' "$backend" "not built"
        continue
    fi
    wall() {
        local start
        start=$(date +%s.%N)
        LD_LIBRARY_PATH=$libtorch/lib:${LD_LIBRARY_PATH:-} "$binary" train --config configs/keypoint-slim.toml \
            --dataset "$dataset" --out "$out/$backend-$1" --steps "$1" --backend "$backend" >"$out/$backend-$1.log" 2>&1
        python3 -c "import time; print(time.time() - $start)"
    }
    short=$(wall "$first")
    long=$(wall $((first + steps)))
    seconds=$(python3 -c "print(($long - $short) / $steps)")
    reference=${reference:-$seconds}
    bare=${slim_step_ms[$backend]:-}
    printf '%-8s %12.2f %9.2f× %15s\n' "$backend" "$(python3 -c "print(1/$seconds)")" "$(python3 -c "print($reference/$seconds)")" \
        "$([[ -n $bare ]] && python3 -c "print(f'{1000 * $seconds / $bare:.2f}×')" || echo "-")"
done
