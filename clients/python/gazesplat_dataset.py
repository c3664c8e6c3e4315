"""Compatibility module: gazesplat.dataset (the PyTorch Dataset) under its
former name. New code: `from gazesplat.dataset import RedirectedGazeDataset`."""
import gazesplat_client  # noqa: F401  (finds the package)
from gazesplat.dataset import *  # noqa: E402,F401,F403
