"""mogo-export: train MOGO text-to-motion models in PyTorch and export them as ONNX bundles."""
__version__ = "0.1.0"
