"""Files a command writes: the output-path guard (output_paths), one owner per folder (run_lock), hidden work folders (work_folder)."""
