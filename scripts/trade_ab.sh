#!/bin/bash
# `bench trade` of two commits alternated (A/B, then B/A), for ratios measured against each
# other on a shared machine whose load drifts.
#
#   scripts/trade_ab.sh REF_A REF_B ROUNDS "scene:width:height ..." [SPP] [OUT]
#   scripts/trade_ab.sh main HEAD 2 "museum_soft:320:240 museum_1999:640:480" 1,4 /tmp/ab
#
# Each ref is exported (git archive) into OUT/A and OUT/B, and each run starts in its own
# tree: `python -m` puts the working directory first on sys.path, so a run started in a
# checkout measures that checkout whatever PYTHONPATH says. Per round and scene, A then B
# (odd rounds) or B then A (even rounds), each `bench trade --spp SPP --epsilons 0.01
# --repeat 1 --threads 1 --clock cpu --json` into OUT/<scene>_<A|B>_<round>.json; OUT/log
# has each run's end time and the load before it. Summarise with
# `python scripts/trade_ab_summary.py OUT`.
set -u
A=$1; B=$2; ROUNDS=$3; SCENES=$4; SPP=${5:-1,4}; OUT=${6:-/tmp/trade_ab}
PY=${PYTHON:-python}
ROOT=$(git rev-parse --show-toplevel)
mkdir -p "$OUT/A" "$OUT/B"
git -C "$ROOT" archive "$A" | tar -x -C "$OUT/A"
git -C "$ROOT" archive "$B" | tar -x -C "$OUT/B"
echo "A $(git -C "$ROOT" rev-parse --short "$A") B $(git -C "$ROOT" rev-parse --short "$B")" >> "$OUT/log"
for r in $(seq 1 "$ROUNDS"); do
  for sc in $SCENES; do
    IFS=: read -r name w h <<< "$sc"
    if [ $((r % 2)) -eq 1 ]; then order="A B"; else order="B A"; fi
    for who in $order; do
      load=$(cut -d' ' -f1 /proc/loadavg)
      (cd "$OUT/$who" && PYTHONPATH="$OUT/$who" "$PY" -m rstrace_engine.bench trade \
        --scenes "$name" --width "$w" --height "$h" --spp "$SPP" --epsilons 0.01 \
        --repeat 1 --threads 1 --clock cpu --json --out "$OUT/tmp_$who" \
        > "$OUT/${name}_${who}_$r.json" 2> "$OUT/${name}_${who}_$r.err")
      echo "$(date +%T) $name $who round $r load-before $load rc $?" >> "$OUT/log"
    done
  done
done
