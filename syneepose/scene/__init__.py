"""Segment planning without Blender (numpy; trimesh for the visibility and collision checks, cv2 for the
marker board): cameras, lights, backdrops and arm motion for one video segment, the ChArUco board bolted to
the end-effector and calibration stations, as a plain SegmentSpec that syneepose/blender renders."""
