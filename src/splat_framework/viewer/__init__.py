"""The local web viewer (scene_viewer), where it listens (serving) and what its clients may do (viser_clients)."""
