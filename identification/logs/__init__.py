"""Seek logs: the :class:`SeekLog` container and seek segmentation (:mod:`.seeklog`), file
formats (:mod:`.formats`)."""
from identification.logs.seeklog import (COLUMNS, MIN_SAMPLES, LogError, Seek, SeekLog, segment_seeks,
                                         settle_windows)
from identification.logs.formats import FORMAT_VERSION, read_log, write_log

__all__ = ["COLUMNS", "MIN_SAMPLES", "FORMAT_VERSION", "LogError", "Seek", "SeekLog", "read_log", "write_log",
           "segment_seeks", "settle_windows"]
