"""Live online navigation from a measurement stream (``fgnav follow``): the stream reader
(:mod:`fgnav.online.stream`), the navigator (:mod:`fgnav.online.navigator`) and the files
a live run grows (:mod:`fgnav.online.live_files`)."""

from fgnav.online.navigator import Navigator, State
from fgnav.online.stream import LineSource, Row, StreamReader

__all__ = ["Navigator", "State", "StreamReader", "LineSource", "Row"]
