#!/usr/bin/env bash
# Renders the detail data of issue 18 (resumable: re-run to continue; frames already written are
# skipped). Scenes with fine detail (radn_datagen/detail.py): a textured wall with bump behind a
# fence of thin wires, small text, fine textures, chrome, gold and glass.
#   detail-test   held aside: never used in training or model selection. 192x112, 8 frames,
#                 inputs at 4 / 11 / 32 spp plus 64 and 128 spp, 512-spp reference of frames 3-6.
#   detail-val    model selection: the same levels, 256-spp references of frames 3-5 (frame 4 alone
#                 before 2026-12-04; frames 3 and 5 give flicker on validation), OIDN teacher.
#   detail-train  per scene a base count n of 16..256 spp (levels 4, n/e, n), resolution 160 or
#                 128 px square, 6 frames, and the OIDN teacher (an independent n-spp render).
#   train-t       general scenes (radn_datagen/scene.py: hair, grass, the original generator)
#                 rendered like detail-train (160 or 128 px, 6 frames, n of 16..128 spp) with the
#                 OIDN teacher; the stage-6 default trained on 15 detail-train + 8 of these.
#   train-fur     the first train-split scenes with particle hair (`--with-hair`; about one
#                 general scene in six has it), rendered like train-t into the same folder.
#   fur-train     scenes with fur and grass in view (radn_datagen/fur.py), rendered like train-t
#                 at 16..64 spp with the OIDN teacher.
#   fur-val       model selection for fur: like detail-val (4 / 11 / 32 spp plus 64 and 128),
#                 256-spp references of frames 3-5; with it, the first val-split scene with hair.
#   fur-test      held aside: 4 / 11 / 32 spp, 512-spp references of frames 3-6.
#   contact-train glass standing on a finely textured floor, lit to throw caustics
#                 (radn_datagen/contact.py), rendered like fur-train.
#   contact-val   model selection for it: 4 / 11 / 32 spp, 256-spp references of frames 3-5.
#   contact-test  held aside: 4 / 11 / 32 spp, 512-spp references of frames 3-6.
#   glass-val     model selection for caustics through glass: the first val-split scenes with at
#                 least three glass objects (`--with-glass`), 4 / 11 / 32 spp, 256-spp references
#                 of frames 3-5.
#   val-256       model selection in the original test split's regime: general val-split scenes
#                 at its 256x256 and lens, 4 / 11 / 32 spp, 256-spp references of frames 4-5
#                 (the test split's 3 000 000 and 3 000 002, where radn trails OIDN, are 256 px
#                 scenes scoring 41-47 dB; every other validation set is 192x112 at 33-38 dB).
#   wires-val     model selection for one-pixel detail under subpixel motion: the first val-split
#                 scenes with thin wires and a moving camera (`--with-wires`; held-aside 3 000 000
#                 has static wires under a panning camera), rendered like val-256.
# Usage: [DETAIL_TRAIN=90 DETAIL_VAL=4 DETAIL_TEST=4 TRAIN_T=16 TRAIN_FUR=4 FUR_TRAIN=5 FUR_VAL=3 FUR_TEST=2 GLASS_VAL=2 CONTACT_TRAIN=5 CONTACT_VAL=2 CONTACT_TEST=2 VAL_256=2 WIRES_VAL=3] tools/datagen/make_detail_dataset.sh [OUT]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-/work/data/radn}"
cd "$here"
py=python3
$py -m radn_datagen dataset --split detail-test --scenes "${DETAIL_TEST:-4}" --frames 1-8 --res 192x112 --spp 32 \
    --extra-spp 64,128 --reference-spp 512 --reference-frames 3-6 --half --out "$out/detail-test"
$py -m radn_datagen dataset --split detail-val --scenes "${DETAIL_VAL:-4}" --frames 1-8 --res 192x112 --spp 32 \
    --extra-spp 64,128 --reference-spp 256 --reference-frames 3-5 --teacher-spp 128 --half --out "$out/detail-val"
$py -m radn_datagen dataset --split detail-train --scenes "${DETAIL_TRAIN:-90}" --frames 1-6 --res 160x160 \
    --res-scales 1,0.8 --spp 16,32,64,128,256 --teacher-spp 1x --half --out "$out/detail-train"
$py -m radn_datagen dataset --split train --scenes "${TRAIN_T:-16}" --frames 1-6 --res 160x160 \
    --res-scales 1,0.8 --spp 16,32,64,128 --teacher-spp 1x --half --out "$out/train-t"
$py -m radn_datagen dataset --split train --with-hair --scenes "${TRAIN_FUR:-4}" --frames 1-6 --res 160x160 \
    --res-scales 1,0.8 --spp 16,32,64,128 --teacher-spp 1x --half --out "$out/train-t"
$py -m radn_datagen dataset --split fur-train --scenes "${FUR_TRAIN:-5}" --frames 1-6 --res 160x160 \
    --res-scales 1,0.8 --spp 16,32,64 --teacher-spp 1x --half --out "$out/fur-train"
$py -m radn_datagen dataset --split fur-val --scenes "${FUR_VAL:-3}" --frames 1-8 --res 192x112 --spp 32 \
    --extra-spp 64,128 --reference-spp 256 --reference-frames 3-5 --half --out "$out/fur-val"
$py -m radn_datagen dataset --split val --with-hair --scenes 1 --frames 1-8 --res 192x112 --spp 32 \
    --extra-spp 64,128 --reference-spp 256 --reference-frames 3-5 --half --out "$out/fur-val"
$py -m radn_datagen dataset --split fur-test --scenes "${FUR_TEST:-2}" --frames 1-8 --res 192x112 --spp 32 \
    --reference-spp 512 --reference-frames 3-6 --half --out "$out/fur-test"
$py -m radn_datagen dataset --split val --with-glass --scenes "${GLASS_VAL:-2}" --frames 1-8 --res 192x112 --spp 32 \
    --reference-spp 256 --reference-frames 3-5 --half --out "$out/glass-val"
$py -m radn_datagen dataset --split contact-train --scenes "${CONTACT_TRAIN:-5}" --frames 1-6 --res 160x160 \
    --res-scales 1,0.8 --spp 16,32,64 --teacher-spp 1x --half --out "$out/contact-train"
$py -m radn_datagen dataset --split contact-val --scenes "${CONTACT_VAL:-2}" --frames 1-8 --res 192x112 --spp 32 \
    --reference-spp 256 --reference-frames 3-5 --half --out "$out/contact-val"
$py -m radn_datagen dataset --split contact-test --scenes "${CONTACT_TEST:-2}" --frames 1-8 --res 192x112 --spp 32 \
    --reference-spp 512 --reference-frames 3-6 --half --out "$out/contact-test"
$py -m radn_datagen dataset --split val --scenes "${VAL_256:-2}" --frames 1-7 --res 256x256 --spp 32 \
    --reference-spp 256 --reference-frames 4-5 --half --out "$out/val-256"
$py -m radn_datagen dataset --split val --with-wires --scenes "${WIRES_VAL:-3}" --frames 1-7 --res 256x256 --spp 32 \
    --reference-spp 256 --reference-frames 4-5 --half --out "$out/wires-val"
