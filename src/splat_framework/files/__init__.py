"""Files a command writes: atomic writes (io), the output-path guard (output_paths), hidden work folders (work_folder)."""
