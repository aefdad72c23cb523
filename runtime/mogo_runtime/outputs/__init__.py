"""What a motion becomes: files (.npy, .json, .bvh, .glb, .gif, .mp4), game rigs and retargeting onto them."""
