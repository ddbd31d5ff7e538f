"""Pure-numpy scene sampling: cameras, lights, backdrops and arm motion for one video segment."""
