"""The Capture model and loaders for each on-disk layout."""

from .model import Capture, Frame

__all__ = ["Capture", "Frame"]
