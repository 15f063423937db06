#!/usr/bin/env bash
# Renders radn's Mitsuba 3 splits (resumable: re-run to continue). The test split is held aside:
# never used for training or model selection. Usage:
#   [TRAIN_SCENES=60 VAL_SCENES=6 TEST_SCENES=6] tools/mtsgen/make_dataset.sh [OUT]   (OUT: /work/data/mts)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-/work/data/mts}"
cd "$here"
py="python3 -u"
$py -m radn_mtsgen dataset --split test --scenes "${TEST_SCENES:-6}" --frames 1-12 \
    --levels low:4,spp0016:16,spp0064:64 --reference-spp 2048 --reference-frames 4-9 --out "$out/test"
$py -m radn_mtsgen dataset --split val --scenes "${VAL_SCENES:-6}" --frames 1-8 \
    --levels low:4,half:16,high:64 --reference-spp 1024 --reference-frames 4-5 --out "$out/val"
$py -m radn_mtsgen dataset --split train --scenes "${TRAIN_SCENES:-60}" --frames 1-8 \
    --levels low:4,half:16,high:64 --out "$out/train"
# the same test scenes with the renderer's variance (variance.R/G/B), sharing the test references,
# and a validation split with it (how the variance blends were chosen)
$py -m radn_mtsgen dataset --split test --scenes "${TEST_SCENES:-6}" --frames 1-12 \
    --levels low:4,spp0016:16,spp0064:64 --variance --out "$out/test-var"
for s in "$out"/test/scene_*; do ln -sfn "$s/ref" "$out/test-var/$(basename "$s")/ref"; done
$py -m radn_mtsgen dataset --split val --scenes "${VAL_SCENES:-6}" --frames 1-8 \
    --levels low:4,half:16,high:64 --reference-spp 1024 --reference-frames 4-5 --variance \
    --out "$out/val-var"
