"""A generated building: its plan (`plan`: aisles, a planned row per rack face, the passes that scan them), how
its racks are built (`rack_build`), its ground truth (`truth`), a rescan after seeded changes (`rescan`,
`changes`) and the writer (`generate.generate_building`). Stands on the row generator; it never imports this.
See docs/waresynth.md, "Buildings".
"""
