"""radn's second data generator: animated scenes rendered with Mitsuba 3 (PyPI), written in
radn's generic EXR layout with exact motion vectors. Its scene code shares nothing with
tools/datagen (Cycles), so its held-aside split tests transfer to another generator and another
renderer."""
