"""Inference: the streaming/windowed predictor, frozen CPU graphs, frame fusion, camera levelling and
Table I evaluation."""
