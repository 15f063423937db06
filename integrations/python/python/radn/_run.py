"""Running the `radn` binary: arguments from Python values, progress from its JSON lines,
errors as exceptions carrying radn's own message, cancellation that leaves no partial file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Optional, Sequence, Tuple, Union

from ._binary import binary_path

PathLike = Union[str, "os.PathLike[str]"]
Frames = Union[None, str, range, Tuple[int, int]]
Progress = Callable[[float, int], Any]

#: exit status radn uses for a run that was asked to stop
_CANCELLED_STATUS = 130


class RadnError(RuntimeError):
    """radn failed; the message is radn's (it names the file and the problem)."""

    def __init__(self, message: str, returncode: int = 1, log: str = "") -> None:
        super().__init__(message)
        #: radn's exit status
        self.returncode = returncode
        #: everything radn wrote to stderr besides progress lines
        self.log = log


class Cancelled(RadnError):
    """The run was cancelled; frames finished before are kept, none is left half-written."""


@dataclass(frozen=True)
class DenoiseResult:
    """What a finished :func:`denoise` did."""

    #: frames denoised and written by this run
    written: int
    #: frames whose output already existed (skipped, to resume)
    skipped: int
    #: NaN/Inf input samples repaired
    repaired: int
    #: wall time of the run, seconds
    seconds: float
    #: the path radn chose, e.g. "guided path: … over Intel Open Image Denoise 2.5.1 (…)"
    path: str
    #: radn's standard output
    messages: Sequence[str] = field(default_factory=tuple)


def _frames_arg(frames: Frames) -> Optional[str]:
    """radn's FIRST-LAST[xSTEP] from a string, a (first, last) pair or a range."""
    if frames is None:
        return None
    if isinstance(frames, str):
        return frames
    if isinstance(frames, range):
        if len(frames) == 0 or frames.step < 1:
            raise ValueError(f"frames: {frames!r} is empty or runs backwards")
        last = frames[-1]
        return f"{frames.start}-{last}" + (f"x{frames.step}" if frames.step > 1 else "")
    first, last = frames
    return f"{int(first)}-{int(last)}"


def _stop(proc: "subprocess.Popen[str]") -> None:
    """Asks radn to stop at its next band (it removes its temporary files as it stops)."""
    if proc.poll() is not None:
        return
    try:
        if os.name == "nt":
            proc.send_signal(signal.CTRL_BREAK_EVENT)
        else:
            proc.send_signal(signal.SIGTERM)
    except (ProcessLookupError, OSError):
        pass


def _run(
    args: list[str],
    env: Optional[dict] = None,
    on_event: Optional[Callable[[dict], Any]] = None,
    cancel: Optional[threading.Event] = None,
) -> Tuple[list[str], list[str]]:
    """Runs radn with `args`; returns (stdout lines, stderr lines other than events)."""
    cmd = [str(binary_path()), "--progress", "json", *args]
    flags = subprocess.CREATE_NEW_PROCESS_GROUP if os.name == "nt" else 0
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        encoding="utf-8",
        errors="replace",
        env=env,
        creationflags=flags,
    )
    out: list[str] = []
    reader = threading.Thread(target=lambda: out.extend(proc.stdout), daemon=True)  # type: ignore[arg-type]
    reader.start()
    stopped = threading.Event()
    watcher = None
    if cancel is not None:

        def watch() -> None:
            while proc.poll() is None:
                if cancel.wait(0.1):
                    stopped.set()
                    _stop(proc)
                    return

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
    log: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if line.startswith('{"event"'):
                try:
                    event = json.loads(line)
                except ValueError:
                    log.append(line)
                    continue
                if on_event is not None:
                    on_event(event)
            else:
                log.append(line)
        proc.wait()
    except BaseException:
        # the callback raised, or Ctrl-C in Python: stop radn cleanly before passing it on
        stopped.set()
        _stop(proc)
        proc.wait()
        raise
    finally:
        reader.join()
        if watcher is not None:
            watcher.join()
    if proc.returncode != 0:
        errors = [line.strip()[len("error: "):] for line in log if line.startswith("error: ")]
        message = errors[-1] if errors else "".join(log).strip() or f"radn exited with status {proc.returncode}"
        if proc.returncode == _CANCELLED_STATUS or stopped.is_set():
            raise Cancelled(message, proc.returncode, "".join(log))
        raise RadnError(message, proc.returncode, "".join(log))
    return [line.rstrip("\n") for line in out], log


def denoise(
    input: PathLike,
    output: PathLike,
    frames: Frames = None,
    guide: str = "auto",
    aovs: Iterable[str] = (),
    progress: Optional[Progress] = None,
    *,
    strength: Optional[float] = None,
    motion: Optional[str] = None,
    overwrite: bool = False,
    device: Optional[str] = None,
    model: Optional[PathLike] = None,
    threads: Optional[int] = None,
    oidn_library: Optional[PathLike] = None,
    cancel: Optional[threading.Event] = None,
    extra_args: Sequence[str] = (),
) -> DenoiseResult:
    """Denoises an EXR sequence with radn's best path for it.

    input, output: sequence patterns (`beauty.####.exr`, `%04d`, `$F4`) or, for input, a
    folder; every layer of the input is kept in the output, which is never written over an
    input. frames: "FIRST-LAST[xSTEP]", (first, last) or a range (default: all). guide: "auto"
    (Intel Open Image Denoise when found: the guided path), "none", "oidn", "denoised" or a
    layer name. aovs: extra layers denoised with the beauty's weights. progress: called with
    (frames done, frames in all) as the run goes, done counting every stage and fractions of a
    frame. strength: 1 as tuned, lower keeps more of the input. motion: "auto" (the renderer's
    vectors where the files have them, else motion estimated from the frames), "renderer" or
    "estimate" (for renders with motion blur, which have no vectors). overwrite: recompute outputs
    that exist (default: skip them, to resume). device: "cpu" or "cuda[:N]". oidn_library: the
    OIDN library to guide with (for example Blender's). cancel: set it to stop the run
    (raises :class:`Cancelled`). extra_args: further `radn denoise` options.

    Raises :class:`RadnError` with radn's message when the run fails.
    """
    args = ["denoise", "-i", os.fspath(input), "-o", os.fspath(output), "--guide", guide]
    f = _frames_arg(frames)
    if f is not None:
        args += ["--frames", f]
    aov_list = [a.strip() for a in aovs if a.strip()]
    if aov_list:
        args += ["--aovs", ",".join(aov_list)]
    if strength is not None:
        args += ["--strength", repr(float(strength))]
    if motion is not None:
        args += ["--motion", motion]
    if overwrite:
        args.append("--overwrite")
    if device is not None:
        args += ["--device", device]
    if model is not None:
        args += ["--model", os.fspath(model)]
    if threads is not None:
        args += ["--threads", str(int(threads))]
    args += list(extra_args)
    env = None
    if oidn_library is not None:
        env = dict(os.environ, RADN_OIDN_LIBRARY=os.fspath(oidn_library))

    finished: dict = {}

    def on_event(event: dict) -> None:
        if event.get("event") == "finished":
            finished.update(event)
        elif event.get("event") == "progress" and progress is not None:
            total = int(event.get("frames", 0))
            progress(float(event.get("fraction", 0.0)) * total, total)

    out, _ = _run(args, env=env, on_event=on_event, cancel=cancel)
    path = next((line[len("radn: "):] for line in out if line.startswith("radn: ")), "")
    return DenoiseResult(
        written=int(finished.get("written", 0)),
        skipped=int(finished.get("skipped", 0)),
        repaired=int(finished.get("repaired", 0)),
        seconds=float(finished.get("seconds", 0.0)),
        path=path,
        messages=tuple(out),
    )


def inspect(path: PathLike) -> dict:
    """An EXR's parts, channels, sample types, size and value statistics (`radn inspect --json`).

    Raises :class:`RadnError` when the file cannot be read.
    """
    out, _ = _run(["inspect", "--json", os.fspath(Path(path))])
    return json.loads("\n".join(out))
