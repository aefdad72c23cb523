"""The bundle contract: the manifest typed and checked (sections.py, manifest.py), the sampling settings it carries
(sampling.py), and the folder whose files are confined and hashed as they are read (folder.py)."""
from .folder import Bundle, read_manifest, sha256_file
from .manifest import Manifest
from .sections import GRAPHS, BundleError

__all__ = ["Bundle", "BundleError", "GRAPHS", "Manifest", "read_manifest", "sha256_file"]
