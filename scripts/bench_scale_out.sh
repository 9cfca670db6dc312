#!/bin/bash
# `make bench-scale-out`: python -m boxpose_ray on a loopback Ray head with 1, then 2 CPUs, against
# the same jobs in one process that renders on every core (docs/scale-out.md, "Speed-up").
# Search: single_box, SAMPLES samples in batches of 10; scenes: single_box, SCENES scenes in 4 shards.
set -euo pipefail
cd "$(dirname "$0")/.."
SAMPLES=${SAMPLES:-80}
SCENES=${SCENES:-16}
OUT=$(mktemp -d /tmp/bench-scale-out.XXXXXX)
trap 'ray stop --force >/dev/null 2>&1 || true; rm -rf "$OUT"' EXIT
export PATH=$PWD/.venv/bin:$PATH RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 RAY_AUTH_MODE=token
RAY_AUTH_TOKEN=$(python -c "import secrets; print(secrets.token_hex(32))")
export RAY_AUTH_TOKEN
PORT=$(python -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
SEARCH=(single_box --samples "$SAMPLES" --batch-size 10 --seed 1)
SCENE=(--recipe single_box --num-scenes "$SCENES" --num-shards 4)

seconds() { local s; s=$(date +%s.%N); "$@" >"$OUT/log" 2>&1 || { cat "$OUT/log"; exit 1; }; echo "$(date +%s.%N) - $s" | bc; }

declare -A t
t[search_1proc]=$(seconds target/release/boxpose search "${SEARCH[@]}" --out "$OUT/search-ref")
t[scenes_1proc]=$(seconds python scripts/make_scenes.py "${SCENE[@]}" --dataset "$OUT/scenes-ref")
for cpus in 1 2; do
  ray start --head --node-ip-address=127.0.0.1 --port="$PORT" --num-cpus=$cpus \
    --include-dashboard=false --disable-usage-stats --temp-dir="$OUT/ray" >/dev/null
  t[search_$cpus]=$(seconds python -m boxpose_ray search --address 127.0.0.1:"$PORT" -- "${SEARCH[@]}" --out "$OUT/search-$cpus")
  t[scenes_$cpus]=$(seconds python -m boxpose_ray scenes --address 127.0.0.1:"$PORT" "${SCENE[@]}" --dataset "$OUT/scenes-$cpus")
  ray stop --force >/dev/null
  cmp -s "$OUT/search-$cpus/samples.parquet" "$OUT/search-ref/samples.parquet" || { echo "search tables differ"; exit 1; }
done
printf '%-8s %14s %14s %12s %16s %14s\n' job "Ray 1 worker" "Ray 2 workers" "1 → 2" "one process" "Ray 2 / one"
for job in search scenes; do
  printf '%-8s %13.1fs %13.1fs %11.2f× %15.1fs %13.2f×\n' $job "${t[${job}_1]}" "${t[${job}_2]}" \
    "$(echo "${t[${job}_1]} / ${t[${job}_2]}" | bc -l)" "${t[${job}_1proc]}" \
    "$(echo "${t[${job}_1proc]} / ${t[${job}_2]}" | bc -l)"
done
echo "search: the Ray runs' samples.parquet equal the single process's byte for byte"
