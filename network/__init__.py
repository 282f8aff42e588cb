"""The MVRackLay network: model, losses, training, Table I evaluation and streaming inference.

Entry points: `network.model.MVRackLay` / `ModelConfig` / `VARIANTS`, `network.train.Trainer`,
`network.evaluate.evaluate_sequences`, `network.infer.Predictor`, `network.checkpoint`
(`load_model`, `save_checkpoint`, `export_weights`). See docs/network.md.
"""

from network.model import DEFAULT_VARIANT, VARIANTS, ModelConfig, MVRackLay

__all__ = ["DEFAULT_VARIANT", "VARIANTS", "ModelConfig", "MVRackLay"]
