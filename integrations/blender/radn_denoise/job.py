"""A radn run in a background thread, so Blender's interface stays live: progress and the
outcome are read by the operator's timer; cancelling stops radn at its next band, which removes
its temporary files (the frames finished before are kept)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence


@dataclass
class JobRequest:
    """What to denoise: radn's arguments, as the panel or the operator gave them."""

    input: str
    output: str
    frames: Optional[str] = None
    strength: float = 1.0
    aovs: Sequence[str] = ()
    #: radn's --motion (None: auto)
    motion: Optional[str] = None
    oidn_library: Optional[str] = None
    overwrite: bool = False


@dataclass
class DenoiseJob:
    """One radn run: start it, poll `done`/`fraction`, `cancel()` it; then `error` or `result`."""

    request: JobRequest
    #: also told of progress (frames done, frames in all), from radn's thread
    on_progress: Optional[Callable[[float, int], None]] = None
    fraction: float = 0.0
    frames_done: float = 0.0
    frames_total: int = 0
    result: object = None
    error: Optional[str] = None
    cancelled: bool = False
    _cancel: threading.Event = field(default_factory=threading.Event)
    _finished: threading.Event = field(default_factory=threading.Event)
    _thread: Optional[threading.Thread] = None

    def start(self) -> "DenoiseJob":
        """Starts radn in a thread."""
        self._thread = threading.Thread(target=self._run, name="radn", daemon=True)
        self._thread.start()
        return self

    def run(self) -> "DenoiseJob":
        """Runs radn in this thread (background mode, scripts)."""
        self._run()
        return self

    @property
    def done(self) -> bool:
        """Whether radn has ended (finished, failed or cancelled)."""
        return self._finished.is_set()

    def cancel(self) -> None:
        """Asks radn to stop at its next band."""
        self._cancel.set()

    def wait(self, timeout: Optional[float] = None) -> None:
        """Waits for the thread to end."""
        if self._thread is not None:
            self._thread.join(timeout)

    def _progress(self, done: float, total: int) -> None:
        self.frames_done, self.frames_total = done, total
        self.fraction = done / total if total else 0.0
        if self.on_progress is not None:
            self.on_progress(done, total)

    def _run(self) -> None:
        try:
            self._denoise()
        finally:
            self._finished.set()

    def _denoise(self) -> None:
        try:
            import radn  # the bundled wheel
        except ImportError as e:  # the zip's wheel did not install
            self.error = f"the radn package is missing from this extension ({e}); reinstall it"
            return
        r = self.request
        try:
            self.result = radn.denoise(
                r.input,
                r.output,
                frames=r.frames,
                aovs=r.aovs,
                progress=self._progress,
                strength=r.strength,
                motion=r.motion,
                overwrite=r.overwrite,
                oidn_library=r.oidn_library,
                cancel=self._cancel,
            )
        except radn.Cancelled:
            self.cancelled = True
            self.error = "cancelled: frames finished before are kept, none is half-written"
        except radn.RadnError as e:
            self.error = str(e)
        except Exception as e:  # a missing binary, an OS error starting it
            self.error = f"{type(e).__name__}: {e}"
