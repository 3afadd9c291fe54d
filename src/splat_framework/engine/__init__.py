"""Running a method: the trainer, checkpoints, run folders, memory plan, random state, profiling, machine resources."""
