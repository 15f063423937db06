#!/usr/bin/env bash
# Renders radn's default training dataset (resumable: re-run to continue) and its
# pseudo-references. Usage: [TRAIN_SCENES=48 VAL_SCENES=6 TEST_SCENES=6] tools/datagen/make_dataset.sh [OUT]
# (OUT defaults to /work/data/radn; the shipped default model used 28/4/3 scenes, see docs/research/model-history.md)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-/work/data/radn}"
cd "$here"
py=python3
$py -m radn_datagen dataset --split train --scenes "${TRAIN_SCENES:-48}" --frames 1-8 --res 256x256 --spp 32 --out "$out/train"
$py -m radn_datagen dataset --split val   --scenes "${VAL_SCENES:-6}"  --frames 1-8 --res 256x256 --spp 32 \
    --reference-spp 256 --reference-frames 4-4 --out "$out/val"
$py -m radn_datagen dataset --split test  --scenes "${TEST_SCENES:-6}"  --frames 1-8 --res 256x256 --spp 32 \
    --reference-spp 512 --reference-frames 4-5 --out "$out/test"
# pseudo-references from the least noisy level, by the classic denoiser
radn="$here/../../target/release/radn"
[ -x "$radn" ] || (cd "$here/../.." && cargo build --release -q -p radn)
for split in train val test; do
  "$radn" pseudoref --data "$out/$split"
done
