"""What leaves a run: PLY files (ply), videos (video), novel-view camera paths (camera_paths)."""
