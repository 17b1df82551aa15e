"""benchmarks/cloth_continuum_speed.py in parts: `config` (constants, materials, run sizes), `scene` (the
sheets, through taichi_anim's public API), `measure` (part 1, f64), `rate` (part 2, f32), `peer` (part 3,
ours against Newton), `tables`, `summary`, `plot` and `report` (the page, its JSON and its plot), and
`run` (the order of the parts). The method is described in the entry point's docstring."""
