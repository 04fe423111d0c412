"""pedrl: multi-agent vector-quantised Q-learning for pedestrian navigation."""

__version__ = "0.1.0"
