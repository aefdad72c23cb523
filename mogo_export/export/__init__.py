"""Export: torch models to self-describing ONNX graphs for the mogo bundle."""
