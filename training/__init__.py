"""PyTorch side of ADSM: the paper's network zoo, datasets, losses, trainer and evaluation."""
