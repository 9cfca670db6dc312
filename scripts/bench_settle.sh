#!/usr/bin/env bash
# Drake vs MuJoCo: time to settle the SAME drops, side by side, in one run.
#
#   scripts/bench_settle.sh                 # 3 scenes each of 5 and 20 boxes, clutter recipe
#   SCENES=5 BOXES="5 10 20" scripts/bench_settle.sh
#
# 1. python -m drake_scenes.bench_settle samples and projects the scenes, settles each with Drake
#    (one JSON line per scene with "drake_settle_s") and writes the initial states to $OUT.
# 2. boxpose settle $OUT --bench settles the same initial states with MuJoCo, reusing each
#    compiled model for $REPEAT settles (median reported), as the search loop does.
# 3. The two are joined per scene and per box count, with the ratio.
# Needs the venv (make setup) and a release build of boxpose (make rust).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
BOXPOSE=${BOXPOSE:-target/release/boxpose}
RECIPE=${RECIPE:-datasets/recipes/clutter.toml}
BOXES=${BOXES:-5 20}
SCENES=${SCENES:-3}
REPEAT=${REPEAT:-5}
OUT=${OUT:-build/bench_settle}

[[ -x $PY ]] || { echo "error: $PY missing: run make setup" >&2; exit 2; }
[[ -x $BOXPOSE ]] || { echo "error: $BOXPOSE missing: run make rust" >&2; exit 2; }
mkdir -p "$(dirname "$OUT")"
# shellcheck disable=SC2086
"$PY" -m drake_scenes.bench_settle --recipe "$RECIPE" --boxes $BOXES --scenes "$SCENES" --out "$OUT" > "$OUT.drake.jsonl"
"$BOXPOSE" settle "$OUT" --bench --repeat "$REPEAT" --json > "$OUT.mujoco.jsonl"

"$PY" - "$OUT.drake.jsonl" "$OUT.mujoco.jsonl" "$RECIPE" "$REPEAT" <<'PYEOF'
import json, statistics, sys
drake = {d["scene_id"]: d for d in map(json.loads, open(sys.argv[1]))}
mujoco = {m["scene_id"]: m for m in map(json.loads, open(sys.argv[2]))}
recipe, repeat = sys.argv[3], sys.argv[4]
print(f"Settle time on the same drops ({recipe}); MuJoCo: median of {repeat} settles reusing the compiled model")
print(f"{'scene':>5} {'boxes':>5} {'Drake s':>9} {'MuJoCo ms':>10} {'ratio':>7}  {'Drake':>8} {'MuJoCo':>8}  same face  max Δcentre")
by_count = {}
for sid, d in sorted(drake.items()):
    m = mujoco.get(sid)
    if d.get("drake_settle_s") is None or m is None or "error" in m:
        print(f"{sid:>5} {d['boxes']:>5}  skipped: {d.get('error') or (m or {}).get('error', 'not settled by MuJoCo')}")
        continue
    ratio = d["drake_settle_s"] / m["mujoco_settle_s"]
    by_count.setdefault(d["boxes"], []).append((d["drake_settle_s"], m["mujoco_settle_s"]))
    verdict = lambda ok: "stable" if ok else "unstable"
    print(f"{sid:>5} {d['boxes']:>5} {d['drake_settle_s']:>9.3f} {m['mujoco_settle_s'] * 1e3:>10.2f} {ratio:>6.0f}×  "
          f"{verdict(d['stable']):>8} {verdict(m['stable']):>8}  {m['faces_agree']:>3}/{m['boxes']:<3}     {m['max_position_diff_m'] * 1e3:6.1f} mm")
print()
print(f"{'boxes':>5} {'scenes':>6} {'Drake s (median)':>17} {'MuJoCo ms (median)':>19} {'ratio':>7}")
for n, rows in sorted(by_count.items()):
    dk, mj = statistics.median(r[0] for r in rows), statistics.median(r[1] for r in rows)
    print(f"{n:>5} {len(rows):>6} {dk:>17.3f} {mj * 1e3:>19.2f} {dk / mj:>6.0f}×")
if 5 in by_count:
    mj5 = statistics.median(r[1] for r in by_count[5]) * 1e3
    print(f"\ngoal MuJoCo ≤ 20 ms per 5-box scene: {mj5:.1f} ms, {'met' if mj5 <= 20 else 'NOT met'}")
PYEOF
