"""The daemon's recording in progress: start, stop, event marks, the full-rate tick window.

One recording at a time (tvsd.daemon.session_recording.SessionRecording), made in the data
directory with no-follow semantics; marks are placed on the control ticks' clock.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

from tvsd.daemon.parts import DaemonParts
from tvsd.daemon.session_recording import SessionRecording
from tvsd.daemon.state import DaemonState
from tvsd.errors import DeviceError
from tvsd.recording.writer import new_recording_dir


class RecordingControl(DaemonParts):
    """The recording in progress (`self.recording`): start, stop, marks, tick windows."""

    def start_recording(self) -> Path:
        """A new recording in the data directory, of everything from now on (none may run)."""
        assert self.recording is None, "one recording at a time"
        try:  # a fresh directory made now (rec-…-2 within the same second), never one planted
            path = new_recording_dir(self.data_dir, time.strftime("rec-%Y%m%d-%H%M%S"))
            self.recording = SessionRecording(path, self.config_text, from_tick=self.runner.ticks)
        except OSError as exc:
            raise DeviceError(f"cannot record into {self.data_dir}: {exc}; check --data-dir") from None
        self.recording_started.set()
        self.mark("state", state=str(self.state), was=None)
        return path

    def record_window(self, seconds: float, reason: str) -> int:
        """The last `seconds` of control ticks at full rate into the recording; how many."""
        assert self.recording is not None, "record_window needs a recording"
        rows = self.runner.recent_ticks(round(seconds * self.cfg.control.rate_hz))
        self.recording.window(rows, reason)
        return len(rows)

    async def stop_recording(self) -> Path | None:
        """Close the recording (fsync off the event loop); its path, or None if none ran."""
        if self.recording is None:
            return None
        rec, self.recording = self.recording, None
        await asyncio.get_running_loop().run_in_executor(None, rec.close)
        return rec.path

    def mark(self, event: str, **data: Any) -> None:
        if self.recording is not None:  # t_loop: on the control ticks' clock, placed by export
            t_loop = (time.monotonic_ns() - self.runner.start_ns) / 1e9
            self.recording.mark(event, t_loop=t_loop, **data)

    def _state_changed(self, old: DaemonState, new: DaemonState) -> None:
        self.mark("state", state=str(new), was=str(old))
