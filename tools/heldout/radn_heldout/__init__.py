"""Held-out Cycles scenes for radn's transfer tests: a scene generator that shares no scene code
with tools/datagen or tools/mtsgen and is never used for training or model selection."""

LEVELS = {"low": 4, "spp0016": 16, "spp0064": 64}
REFERENCE = "ref"
