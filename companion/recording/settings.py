"""``[record]`` of the service's configuration, apart from the recorder
(:mod:`companion.recording.record`, which loads mcap and the Foxglove schemas): the
configuration, and so every process that reads it, needs only these numbers."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RecordSettings:
    """``[record]`` of the service's configuration."""

    enabled: bool = True
    dir: str = ""  # "" = <state_dir>/records
    max_file_mb: float = 100.0  # start a new file beyond this size
    max_total_mb: float = 2000.0  # delete the oldest records beyond this total
    queue: int = 20000  # messages waiting for the writer; more are dropped and counted
    # also write the flight in Foxglove's schemas (companion.recording.foxglove)
    foxglove: bool = True
