#!/usr/bin/env bash
# Renders radn's held-out Cycles test split (resumable: re-run to continue). Held aside for good:
# never used for training or model selection. Usage: [SCENES=8] tools/heldout/make_dataset.sh [OUT]
# (OUT: /work/data/heldout). Seeds 11 000 000+i; the families take turns.
set -euo pipefail
cd "$(dirname "$0")"
python3 -u -m radn_heldout dataset --scenes "${SCENES:-8}" --frames 1-10 \
    --levels low:4,spp0016:16,spp0064:64 --reference-spp 1024 --reference-frames 4-7 \
    --out "${1:-/work/data/heldout}"
