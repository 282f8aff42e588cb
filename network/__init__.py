"""The MVRackLay network: the model, its depth heads, streaming inference, and training.

Subpackages, each importing only those before it (tests/test_network_layers.py checks the arrows):

* `network.heads` – the heads that read depth (`backedge`, `uprights`: the rack depth; `boxdepth` with the
  plane sweep of `parallax`: each box's depth) and the readers that carry their readings along the row.
* `network.model` – the network itself, its heads among its parts: `config` (`ModelConfig`, `VARIANTS`), `net` (`MVRackLay`), its
  parts (`resnet` encoder, `decoders`, `memory` with `convlstm`, `discriminator`), the camera motion read
  from the images (`motion`) and the CPU graphs its parts run as at inference (`frozen`).
* `network.inference` – running a model: `predictor` (`Predictor`), `decision` (the record's calibrated
  offsets), `fusion` (frame fusion), `roll` (camera levelling, the angles read by `angle_reading`),
  `evaluate` (Table I).
* `network.training` – making one: `trainer` (`Trainer`; its settings in `train_config`, its data opened by
  `train_data`, its records in `run_records`), `losses`, `distributed`, `curves`, `toy`, `calibrate`, and the
  fits of the heads on a frozen model (`fit_back_edges`, `fit_uprights`, `fit_box_depth`, whose inputs come
  from `head_inputs` and are cached by `box_cache`, kept between fits by `kept_box_cache`).

On top: `network.fastops` (exact, faster CPU resampling ops), `network.data` (datasets and the canonical warp), `network.checkpoint` (`load_model`,
`save_checkpoint`, `export_weights`) and `network.precision`. See docs/network.md.
"""

from network.model.config import DEFAULT_VARIANT, VARIANTS, ModelConfig
from network.model.net import MVRackLay

__all__ = ["DEFAULT_VARIANT", "VARIANTS", "ModelConfig", "MVRackLay"]
