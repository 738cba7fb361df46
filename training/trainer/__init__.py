"""The trainer: batches as a function of the step, the objective module, the loop (see training/train.py)."""

from training.trainer.batches import BatchSpec, TrainingData
from training.trainer.loop import TrainConfig, train

__all__ = ["BatchSpec", "TrainConfig", "TrainingData", "train"]
