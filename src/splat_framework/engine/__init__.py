"""Running a method: the trainer, checkpoints, run folders, the memory plan."""
