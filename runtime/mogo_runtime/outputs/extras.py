"""What each output format needs beyond the core install (numpy + onnxruntime), and the pip extra that brings it.

A game or a phone runs the runtime to get joints and never writes a preview: `pip install mogo-runtime` installs
numpy and onnxruntime only (the tokenizer is the runtime's own), and the writers below are extras:

    pip install "mogo-runtime[preview]"    # .gif previews (pillow)
    pip install "mogo-runtime[video]"      # .mp4 previews (pillow + imageio-ffmpeg: its ffmpeg binary is 165 MB)
    pip install "mogo-runtime[gltf]"       # .glb files (pygltflib)
    pip install "mogo-runtime[all]"

`require(suffix)` is called before any work (outputs.motion.check_output_path), so a missing extra is one error
naming it, not a traceback after generating. runtime/pyproject.toml lists the same extras.
"""
from __future__ import annotations

import importlib.util

# output extension -> (pip extra, [(module, the package that installs it)])
EXTRAS = {".gif": ("preview", [("PIL", "pillow")]),
          ".mp4": ("video", [("PIL", "pillow"), ("imageio_ffmpeg", "imageio-ffmpeg")]),
          ".glb": ("gltf", [("pygltflib", "pygltflib")]),
          # not files: the motion server (`mogo serve`) and its Ray Serve deployment
          "serve": ("serve", [("websockets", "websockets")]),
          "ray": ("ray", [("websockets", "websockets"), ("ray", "ray[serve]")])}


class MissingExtra(ImportError):
    """An output format whose optional packages are not installed; the message names the pip extra."""


def require(suffix: str) -> None:
    """Raise MissingExtra when writing `suffix` files needs a package this install lacks."""
    if suffix not in EXTRAS:
        return
    extra, modules = EXTRAS[suffix]
    missing = [package for module, package in modules if importlib.util.find_spec(module) is None]
    if missing:
        what = f"writing {suffix} files" if suffix.startswith(".") else f"mogo {suffix}"
        raise MissingExtra(f"{what} needs {' and '.join(missing)}, which this install lacks: "
                           f"pip install \"mogo-runtime[{extra}]\"")
