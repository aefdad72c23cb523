"""Tokens on the wire: the token-stream format (format.py), its writer for a crowd's characters (tap.py) and a
decode-only client (client.py) that turns a stream back into frames with the lookup and decoder graphs alone."""
from .client import MotionClient
from .format import RecordReader, WireError

__all__ = ["MotionClient", "RecordReader", "WireError"]
