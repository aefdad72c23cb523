"""mogo-runtime: text to 3D human motion from a mogo bundle, with numpy and onnxruntime only (no torch).

    from mogo_runtime import MotionGenerator
    motion = MotionGenerator("bundles/base").generate("a person walks forward", seconds=4, seed=1)
    motion.save("walk.bvh")
"""
from .bundle import Bundle, BundleError
from .generator import Frame, MotionGenerator
from .motion import Motion
from .sampling import SamplingConfig

__all__ = ["Bundle", "BundleError", "Frame", "Motion", "MotionGenerator", "SamplingConfig"]
