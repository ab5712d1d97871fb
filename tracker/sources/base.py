"""The :class:`FrameSource` interface that every source of RGB-D frames implements."""

from __future__ import annotations

import abc
from collections.abc import Iterator
from typing import Any

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics


class SourceError(RuntimeError):
    """A source could not deliver frames; the message says what failed and what to do."""


class FrameSource(abc.ABC):
    """An iterable of :class:`Frame` objects with metadata.

    ``for frame in source`` yields frames in order; iteration ends when the source is exhausted
    (a live camera never ends on its own). ``close()`` releases devices and files and is idempotent.
    """

    name: str = "source"

    @property
    @abc.abstractmethod
    def intrinsics(self) -> Intrinsics:
        """Intrinsics of the colour image (depth is registered to it)."""

    @abc.abstractmethod
    def __iter__(self) -> Iterator[Frame]: ...

    def metadata(self) -> dict[str, Any]:
        """Description of the source: at least ``name`` and ``intrinsics``; sources add their own."""
        return {"name": self.name, "intrinsics": self.intrinsics.to_dict()}

    def close(self) -> None:  # noqa: B027 - default: nothing to release
        """Release resources."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
