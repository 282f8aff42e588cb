"""Baselines that need no learning, to put the network's figures in context."""
