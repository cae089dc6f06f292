"""Camera poses: COLMAP (pycolmap), similarity alignment, poses estimated from the photons.

colmap      COLMAP poses and their error against reference poses (rule ``colmap_poses``)
alignment   similarity alignment of estimated onto reference cameras; pose and reprojection errors
estimate    poses from the photons: COLMAP on a source's training views, for stage 2 (``estimate_poses``)
"""
