#!/usr/bin/env bash
# Renders radn's held-out motion split (resumable: re-run to continue): Cycles scenes rendered
# with motion blur (no usable vectors, every level and the 1024-spp reference blurred alike), one
# with a camera three times as fast, and a sequence with a cut: the first scene, then another shot
# at its size.
# Held aside for good. Usage: [SCENES=3] tools/heldout/make_motion_dataset.sh [OUT]
# (OUT: /work/data/heldout-motion). Seeds 11 100 000+i; the families take turns.
set -euo pipefail
cd "$(dirname "$0")"
out="${1:-/work/data/heldout-motion}"
common=(--frames 1-10 --levels low:4,spp0016:16,spp0064:64 --reference-spp 1024 --reference-frames 4-7)
python3 -u -m radn_heldout dataset --scenes "${SCENES:-3}" --first-seed 11100000 --motion-blur "${common[@]}" \
    --out "$out"
python3 -u -m radn_heldout dataset --scenes 1 --first-seed 11100100 --motion-blur --camera-speed 3 "${common[@]}" \
    --out "$out/fast"
# the cut: scene 11 100 000, then another shot rendered at its size from frame 4 on
res=$(python3 -c 'import json, sys; print("x".join(map(str, json.load(open(sys.argv[1]))["resolution"])))' \
    "$out/scene_11100000/manifest.json")
python3 -u -m radn_heldout scene --seed 11100201 --res "$res" --motion-blur --frames 4-10 \
    --levels low:4,spp0016:16,spp0064:64 --reference-spp 1024 --reference-frames 4-7 --out "$out/cut/second"
[ -d "$out/cut/scene_cut" ] || python3 -u -m radn_heldout join --out "$out/cut/scene_cut" \
    "$out/scene_11100000" "$out/cut/second"
