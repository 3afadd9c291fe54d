"""What leaves a run: the Gaussians as PLY (ply) and the web viewers' formats (spz, sog, splat,
compressed_ply, their shared packing; formats: which writes each), videos (video), novel-view camera
paths (camera_paths)."""
