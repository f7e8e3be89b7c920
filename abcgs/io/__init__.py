"""File input/output: atomic writes, images, PLY."""

from abcgs.io.atomic import atomic_path, write_json, write_text

__all__ = ["atomic_path", "write_json", "write_text"]
