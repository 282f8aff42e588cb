"""Inference: the streaming/windowed predictor, frame fusion, camera levelling and Table I evaluation."""
