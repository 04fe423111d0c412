"""pedrl's version, in its own module: checkpoints record it without importing the package's entry points."""

__version__ = "0.1.0"
