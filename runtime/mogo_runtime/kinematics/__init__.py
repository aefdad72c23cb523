"""The body: skeletons, the motion feature vector, and joints from features (whole motions and frame by frame)."""
