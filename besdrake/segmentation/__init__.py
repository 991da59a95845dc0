"""Behaviour segmentation (vMCI and baselines) and 1-NN movement classification."""
