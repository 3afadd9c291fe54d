"""Running a method: the trainer, checkpoints, run folders and their lock, memory plan, random state, profiling, machine resources."""
