"""Input and output: COLMAP models and dense maps, images, PLY point clouds."""
