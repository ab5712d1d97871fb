"""Frame sources: simulator, recordings on disk, live cameras. See :mod:`tracker.sources.base`."""

from tracker.sources.base import FrameSource, SourceError

__all__ = ["FrameSource", "SourceError"]
