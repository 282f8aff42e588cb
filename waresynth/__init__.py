"""WareSynth: procedural synthetic warehouses with ground-truth rack layouts.

`waresynth.generate.generate_dataset` writes a dataset (docs/waresynth.md);
`waresynth.dataset.open_dataset` reads one without torch.
"""
