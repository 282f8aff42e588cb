"""The MVRackLay network: model, losses, training, Table I evaluation and streaming inference.

Entry points: `network.model.net.MVRackLay` / `ModelConfig` / `VARIANTS`, `network.training.trainer.Trainer`,
`network.inference.evaluate.evaluate_sequences`, `network.inference.predictor.Predictor`, `network.checkpoint`
(`load_model`, `save_checkpoint`, `export_weights`). See docs/network.md.
"""

from network.model.net import DEFAULT_VARIANT, VARIANTS, ModelConfig, MVRackLay

__all__ = ["DEFAULT_VARIANT", "VARIANTS", "ModelConfig", "MVRackLay"]
