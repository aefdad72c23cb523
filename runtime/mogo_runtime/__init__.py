"""mogo-runtime: text to 3D human motion from a mogo bundle, with numpy and onnxruntime only (no torch).

    from mogo_runtime import MotionGenerator
    motion = MotionGenerator("bundles/base").generate("a person walks forward", seconds=4, seed=1)
    motion.save("walk.bvh")

The package follows the pipeline: bundle/ (the contract: manifest, files, sampling settings) -> text.py, tca/
(prompts to embeddings) -> engine.py (the graphs on onnxruntime) -> the loop (policy.py, endless.py, decoding.py,
generator.py, crowd.py) -> kinematics/ (features to joints) and outputs/ (motion files, rigs, previews).
"""
from .bundle.folder import Bundle
from .bundle.sampling import SamplingConfig
from .bundle.sections import BundleError
from .generator import Frame, MotionGenerator
from .outputs.motion import Motion

__all__ = ["Bundle", "BundleError", "Frame", "Motion", "MotionGenerator", "SamplingConfig"]
