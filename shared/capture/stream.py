"""Motion capture streamed live: BVH motion lines over TCP, and a replay source that plays any
clip through the same path (the stand-in for a capture suit, used by the tests and the demo).

**The stream.** Motion capture suites broadcast BVH in real time: once the skeleton (a BVH
header, ``HIERARCHY`` to ``MOTION``, or a BVH file the recorder is given), then one line of
channel values per frame. :class:`ReplaySource` serves a clip that way on a TCP port (the
header, ``Frames: 0`` and ``Frame Time``, then a line per frame paced at the clip's rate).

**Recording** (:func:`record`) reads such a stream into a take (a BVH file, read back with the
project's reader, so every studio convention applies) and reports what happened, never
silently:

* a frame line with the wrong number of values, or values that are not numbers: dropped and
  counted;
* frames the source skipped: the frames due in a silence between two frame lines, less the
  lines that came together at its end, when that is ``GAP`` frames or more. The silence is the
  time the recorder *waited* for the source, not the time between the lines it read: lines that
  came while it was busy (checking the take so far, publishing frames on the bus, another thread
  of its service holding the interpreter) are read at once and are no gap; and lines a network
  stack held back and sent together (Nagle's algorithm meeting delayed acknowledgements: about
  40 ms) are late, not missing. (Measured between the lines read, a take replayed at 4x through
  the capture service was said to miss about 4 frames in every 25, none of which was missing.)
* the source stopping (the connection closed, or no line for ``idle`` seconds): the take ends
  there, or, with ``reconnect``, the recorder connects again (up to that many times) and the
  take goes on, the pause reported;
* a new header in the middle of the stream: another skeleton (other joints, channels or bone
  lengths) ends the take before it and is reported (a take holds one skeleton); the same one
  again is noted and the take goes on.

Everything is bounded: the line length, the header's size, the frames of one take.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.errors import BadInput
from shared.motion.clip import Clip

GAP = 2  # frames due in a silence of the source and not come at its end: this many or more are said skipped
MAX_LINE = 1 << 16  # bytes of one line
MAX_HEADER_LINES = 5000
MAX_FRAMES = 120 * 60 * 30  # 30 minutes at 120 fps


# ---------------------------------------------------------------------------- the replay source
class ReplaySource:
    """A clip served as a live BVH stream on ``host:port`` (``port=0``: any free port; see
    :attr:`port`); a list of clips plays one per connection, in turn (a study's takes). ``header=False`` sends frame lines only (the recorder then needs the skeleton
    from a file); ``speed`` plays faster or slower; ``loop`` plays again from the start.
    For tests of the recorder's reports it can misbehave like hardware: ``skip`` (frame indices
    never sent), ``stop_after`` (frames, then the connection closes) and ``switch`` (a clip whose
    header is sent after ``stop_after`` frames instead of closing)."""

    def __init__(self, clip: Clip | Sequence[Clip], host: str = "127.0.0.1", port: int = 0, header: bool = True, speed: float = 1.0,
                 loop: bool = False, skip: set[int] | None = None, stop_after: int | None = None,
                 switch: Clip | None = None, connections: int | None = None, hold: bool = False):
        from shared.io.bvh import bvh_lines

        if not speed > 0:
            raise BadInput(f"speed must be positive, got {speed}", field="speed")
        # a sequence of clips is kept as given: a lazy one (:class:`shared.capture.takes.JoinedTakes`) makes each
        # take when it plays
        clips = clip if isinstance(clip, Sequence) else [clip]
        if not len(clips):
            raise BadInput("nothing to play", field="clip")
        self.clips = clips  # each clip's BVH text is made when it plays (a replay of 50 long clips held them all)
        self.switch_lines = bvh_lines(switch) if switch is not None else None
        self.header, self.speed, self.loop = header, float(speed), loop
        self.skip, self.stop_after = set(skip or ()), stop_after
        self.connections = connections  # serve this many connections, then stop listening
        self.hold = hold  # after the take, keep sending its last frame (a person standing still) until the recorder goes
        self.started: list[float] = []  # time.monotonic() when each connection's first frame was due
        self._sock = socket.create_server((host, port))
        self._sock.settimeout(0.2)
        self.host, self.port = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="replay-source")
        self.served = 0

    def __enter__(self) -> ReplaySource:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def address(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    def start(self) -> ReplaySource:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            if self.connections is not None and self.served >= self.connections:
                self._sock.close()  # gone, as a source switched off: a reconnect finds no one
                return
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.served += 1
            if self.connections is not None and self.served >= self.connections:
                self._sock.close()  # the last connection: stop listening before it ends, so a reconnect
                # racing the end of the stream finds no one (not a backlog the close then resets)
            with conn:
                try:
                    # each frame line leaves when it is due, as a live source's must: Nagle's algorithm would hold
                    # small writes until the recorder's delayed acknowledgement, up to 40 ms of frames at once
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._play(conn)
                except OSError:
                    pass  # the recorder went away
        self._sock.close()

    def _play(self, conn: socket.socket) -> None:
        from shared.io.bvh import bvh_lines

        k = (self.served - 1) % len(self.clips)
        clip = self.clips[k]
        head, rows = bvh_lines(clip)
        dt = 1.0 / (clip.fps * self.speed)

        def send_header(lines):
            conn.sendall(("\n".join(lines + ["Frames: 0", f"Frame Time: {1.0 / clip.fps:.12g}"]) + "\n").encode())

        if self.header:
            send_header(head)
        t0 = time.monotonic()
        self.started.append(t0)
        sent = 0
        while not self._stop.is_set():
            for i, row in enumerate(rows):
                if self._stop.is_set():
                    return
                if self.stop_after is not None and sent >= self.stop_after:
                    if self.switch_lines is not None:
                        other_head, other_rows = self.switch_lines
                        send_header(other_head)
                        for r in other_rows:
                            conn.sendall((r + "\n").encode())
                    return
                wait = t0 + sent * dt - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                sent += 1
                if i in self.skip:
                    continue
                conn.sendall((row + "\n").encode())
            if self.hold:
                while not self._stop.is_set():
                    wait = t0 + sent * dt - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                    sent += 1
                    conn.sendall((rows[-1] + "\n").encode())
            if not self.loop:
                return


# ---------------------------------------------------------------------------- recording
@dataclass
class Take:
    """A recorded take: its BVH file, the clip read from it and what happened on the way."""

    path: Path
    clip: Clip | None
    frames: int
    events: list[str] = field(default_factory=list)
    dropped: int = 0  # malformed lines
    skipped: int = 0  # frames the source left out (gaps)
    reconnects: int = 0
    ended: str = ""
    last_frame: float | None = None  # time.monotonic() when the last frame arrived
    ended_at: float | None = None  # time.monotonic() when the take ended (the source stopped, the time was up)
    frame_time: float | None = None  # seconds per frame

    def to_dict(self) -> dict:
        seconds = self.clip.duration if self.clip is not None else max(self.frames - 1, 0) * (self.frame_time or 0.0)
        return {"path": str(self.path), "frames": self.frames, "events": self.events, "dropped": self.dropped,
                "skipped": self.skipped, "reconnects": self.reconnects, "ended": self.ended, "seconds": seconds}


def parse_source(source: str) -> tuple[str, int]:
    """``tcp://host:port`` (or ``host:port``) -> (host, port)."""
    text = source[len("tcp://"):] if source.startswith("tcp://") else source
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise BadInput(f"a live source is tcp://HOST:PORT, got {source!r}", field="source")
    return host.strip("[]"), int(port)


class _Lines:
    """Lines from a socket, bounded in length; ``None`` at the end of the stream; raises
    TimeoutError after ``idle`` seconds without a line. ``waited``: the seconds the last
    :meth:`next` spent waiting for the source (0 for a line that had already come while the
    reader was busy), so the source's silences are told from the reader's own work; ``burst``:
    how many lines came together at the end of that wait (1 from a source that sends each line as
    it is due; more from one whose network stack holds small writes back, as Nagle's algorithm
    against delayed acknowledgements does for about 40 ms)."""

    def __init__(self, conn: socket.socket, idle: float):
        self.conn, self.buf = conn, b""
        self.waited, self.burst = 0.0, 1
        conn.settimeout(idle)

    def next(self) -> str | None:
        self.waited, self.burst = 0.0, 1
        while b"\n" not in self.buf:
            if len(self.buf) > MAX_LINE:
                raise BadInput(f"a line of the stream is longer than {MAX_LINE} bytes: not BVH", field="source")
            t = time.monotonic()
            chunk = self.conn.recv(65536)
            self.waited += time.monotonic() - t
            if not chunk:
                if self.buf:
                    line, self.buf = self.buf, b""
                    return line.decode("latin-1")
                return None
            self.buf += chunk
            self.burst = self.buf.count(b"\n")
        line, _, self.buf = self.buf.partition(b"\n")
        return line.decode("latin-1").rstrip("\r")


def _skeleton_file(path: Path) -> tuple[list[str], float | None]:
    """A BVH file's header (``HIERARCHY`` to ``MOTION``) and its frame time, read once."""
    try:
        lines = Path(path).read_text(encoding="latin-1").splitlines()
    except OSError as e:
        raise BadInput(f"{path}: cannot read the skeleton file: {e.strerror or e}", field="skeleton") from None
    for i, line in enumerate(lines):
        if line.strip().upper() == "MOTION":
            frame_time = None
            for after in lines[i + 1:i + 3]:
                if after.strip().upper().startswith("FRAME TIME"):
                    try:
                        frame_time = float(after.split(":")[1])
                    except (IndexError, ValueError):
                        frame_time = None
            return lines[:i + 1], frame_time
    raise BadInput(f"{path}: no MOTION line: not a BVH file to take the skeleton from", field="skeleton")


def _skeleton(header: list[str]) -> list[list[str]]:
    """A header's words, line by line: two headers are one skeleton when these are equal."""
    return [line.split() for line in header if line.strip()]


def _channels(header: list[str]) -> int:
    return sum(int(line.split()[1]) for line in header if line.strip().upper().startswith("CHANNELS"))


def record(source: str, out: Path, *, seconds: float | None = None, frames: int | None = None,
           skeleton: Path | None = None, fps: float | None = None, idle: float = 2.0, reconnect: int = 0,
           connect_timeout: float = 5.0, until=None, check_every: float = 0.25, on_frame=None,
           stop_when: threading.Event | None = None, read: bool = True) -> Take:
    """Record a take from a live BVH stream (module docstring) into ``out`` (a .bvh file),
    until ``seconds`` or ``frames`` (whichever first), the source stops, or its skeleton
    changes. ``skeleton``: a BVH file whose header the stream's lines follow (a stream without
    a header); ``fps`` its rate (else the file's).
    ``until(clip)``: called with the take so far every ``check_every`` seconds of frames; the
    take ends when it returns a reason (a source that never stops: a person done repeating).
    ``on_frame(index, values, frame_time)``: called with every frame kept (values as floats);
    ``stop_when``: an event that ends the take when set (checked at every line); ``read=False``:
    the take's clip is not read back (``Take.clip`` None; a service that only keeps the file)."""
    host, port = parse_source(source)
    if seconds is None and frames is None:
        raise BadInput("say how long to record: seconds or frames", field="seconds")
    limit = min(frames or MAX_FRAMES, MAX_FRAMES)
    header, file_frame_time = _skeleton_file(skeleton) if skeleton is not None else (None, None)
    frame_time = 1.0 / fps if fps else file_frame_time
    events: list[str] = []
    out = Path(out)
    rows = _Rows(out)  # the frame lines, kept in a file beside the take as they come
    so_far_numbers = _Numbers() if until is not None else None  # the rows as numbers, for :class:`_SoFar`
    try:
        so_far = _SoFar()
        dropped = skipped = reconnects = 0
        ended = ""
        deadline = None if seconds is None else time.monotonic() + seconds
        last_frame = None
        silence, burst = 0.0, 1  # seconds the recorder waited for the source since the last frame line, and
        # the lines that came at once at the end of that wait (module docstring)
        connected = False
        while True:
            conn, waited = None, time.monotonic()
            while conn is None:  # a source coming back gets connect_timeout seconds to listen again
                try:
                    conn = socket.create_connection((host, port), timeout=connect_timeout)
                except OSError as e:
                    if not connected:
                        raise BadInput(f"no live source at {source}: {e.strerror or e}", field="source") from None
                    if time.monotonic() - waited > connect_timeout:
                        ended = f"the source did not come back within {connect_timeout:g} s"
                        break
                    time.sleep(0.1)
            if conn is None:
                break
            if connected:
                reconnects += 1
                events.append(f"reconnected after frame {len(rows)} ({time.monotonic() - waited:.1f} s)")
            connected = True
            lines = _Lines(conn, idle)
            own_header: list[str] = []
            in_header = False
            stop = False
            with conn:
                while True:
                    if stop_when is not None and stop_when.is_set():
                        ended, stop = "stopped on request", True
                        break
                    if deadline is not None and time.monotonic() >= deadline:
                        ended, stop = f"{seconds:g} s recorded", True
                        break
                    if len(rows) >= limit:
                        ended, stop = f"{len(rows)} frames recorded", True
                        break
                    try:
                        line = lines.next()
                    except TimeoutError:
                        line = None
                        events.append(f"no frame for {idle:g} s after frame {len(rows)}: the source stopped")
                    except OSError as e:
                        line = None
                        events.append(f"the connection broke after frame {len(rows)} ({e.strerror or e})")
                    except BadInput as e:  # a line too long: not BVH; the frames so far are kept
                        if not rows:
                            raise
                        events.append(f"after frame {len(rows)}: {e.message}; the take ends there")
                        ended, stop = "the stream stopped being BVH", True
                        break
                    if line is None:
                        break
                    silence += lines.waited
                    if lines.waited:
                        burst = lines.burst
                    text = line.strip()
                    if not text:
                        continue
                    word = text.split()[0].upper()
                    if word == "HIERARCHY":
                        in_header, own_header = True, [text]
                        continue
                    if in_header:
                        if len(own_header) > MAX_HEADER_LINES:
                            if not rows:
                                raise BadInput(f"a BVH header of more than {MAX_HEADER_LINES} lines: not a skeleton",
                                               field="source")
                            events.append(f"a header of more than {MAX_HEADER_LINES} lines after frame {len(rows)}: "
                                          "the take ends there (the frames so far are kept)")
                            ended, stop = "the stream sent no skeleton", True
                            break
                        own_header.append(line)
                        if word == "MOTION":
                            in_header = False
                            if header is not None and rows:
                                if _skeleton(own_header) != _skeleton(header):
                                    events.append(f"the skeleton changed after frame {len(rows)} ({_channels(header)} -> "
                                                  f"{_channels(own_header)} channels): the take ends there")
                                    ended, stop = "the skeleton changed", True
                                    break
                                events.append(f"the same skeleton sent again after frame {len(rows)}: kept recording")
                            header = own_header
                        continue
                    if word.startswith("FRAME"):  # "Frames: n" / "Frame Time: t"
                        if word == "FRAME" and "TIME" in text.upper():
                            try:
                                frame_time = float(text.split(":")[1])
                            except (IndexError, ValueError):
                                events.append(f"unreadable frame time {text!r}")
                        continue
                    if header is None:
                        raise BadInput("the stream sends frames without a skeleton: give the BVH file it follows "
                                       "(--skeleton)", field="skeleton")
                    values = text.split()
                    try:
                        numbers = [float(v) for v in values]
                        ok = len(values) == _channels(header)
                    except ValueError:
                        ok = False
                    if not ok:
                        dropped += 1
                        if dropped <= 5:
                            events.append(f"dropped a malformed frame line after frame {len(rows)} "
                                          f"({len(values)} values, {_channels(header)} channels)")
                        continue
                    # the frames due in the silence, less those that came at its end together
                    missing = int(round(silence / frame_time)) - burst if frame_time else 0
                    if last_frame is not None and missing >= GAP:
                        skipped += missing
                        events.append(f"about {missing} frame(s) missing after frame {len(rows)} "
                                      f"({silence * 1000:.0f} ms without a frame)")
                    last_frame, silence, burst = time.monotonic(), 0.0, 1
                    rows.append(text)
                    if so_far_numbers is not None:
                        so_far_numbers.append(numbers)
                    if on_frame is not None:
                        on_frame(len(rows) - 1, numbers, frame_time)
                    step = max(int(round(check_every / (frame_time or 1 / 30))), 1)
                    if until is not None and so_far_numbers is not None and len(rows) % step == 0:
                        reason = until(so_far.clip(header, rows, so_far_numbers, frame_time, out))
                        if reason:
                            ended, stop = str(reason), True
                            break
            if stop:
                break
            if reconnects < reconnect:
                silence = 0.0  # the pause is the reconnect's (its own event), not frames skipped
                continue
            ended = ended or "the source stopped"
            break
        ended_at = time.monotonic()
        if dropped > 5:
            events.append(f"{dropped} malformed frame lines dropped in all")
        if header is None or not rows:
            return Take(out, None, 0, events + ["no frames recorded"], dropped, skipped, reconnects, ended or "no frames",
                        last_frame, ended_at)
        from shared.io import load_clip
        from shared.io.atomic import atomic_write

        atomic_write(out, lambda f: rows.write_bvh(f, header, frame_time))
        return Take(out, load_clip(out) if read else None, len(rows), events, dropped, skipped, reconnects, ended,
                    last_frame, ended_at, frame_time or 1 / 30)

    finally:
        rows.close()  # the take's file has the lines now, or there is none


class _Rows:
    """A take's frame lines as they arrive, kept in a temporary file beside the take instead of in
    memory (a 30-minute take at 120 fps is 216,000 lines: as Python strings and numbers they held
    ~2.5 KB a frame); ``len`` is the frames so far."""

    def __init__(self, out: Path):
        import os
        import tempfile

        out.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=".rows-", suffix=".part", dir=out.parent)
        self.path, self._f, self._n = Path(name), os.fdopen(fd, "w+b"), 0

    def __len__(self) -> int:
        return self._n

    def append(self, text: str) -> None:
        self._f.write(text.encode("latin-1") + b"\n")
        self._n += 1

    def write_bvh(self, f, header: list[str], frame_time: float | None) -> None:
        """The take so far as a BVH file into the open binary file ``f``."""
        import shutil

        f.write(("\n".join(header + [f"Frames: {self._n}", f"Frame Time: {frame_time or 1 / 30:.12g}"]) + "\n")
                .encode("latin-1"))
        self._f.flush()
        self._f.seek(0)
        shutil.copyfileobj(self._f, f)
        self._f.seek(0, 2)

    def close(self) -> None:
        self._f.close()
        self.path.unlink(missing_ok=True)


class _Numbers:
    """The frames' numbers so far as one growing array (doubled when full)."""

    def __init__(self):
        import numpy as np

        self._np, self._n = np, 0
        self._data: Any = None  # an array once the first frame came

    def append(self, numbers: list[float]) -> None:
        if self._data is None:
            self._data = self._np.empty((1024, len(numbers)))
        elif self._n == len(self._data):
            self._data = self._np.concatenate([self._data, self._np.empty_like(self._data)])
        self._data[self._n] = numbers
        self._n += 1

    def array(self):
        return self._data[:self._n]


class _SoFar:
    """The take so far as a clip, for ``until``: read once through the BVH reader (conventions
    and all) and, where the reader kept the stream's numbers as they are (checked on the frames
    read), later as the same clip with the new numbers, without writing and reading a file."""

    def __init__(self):
        self.template: Clip | None = None
        self.header: list[str] | None = None

    def clip(self, header: list[str], rows: _Rows, values: _Numbers, frame_time, out: Path) -> Clip:
        import numpy as np

        numbers = values.array()
        if self.template is not None and self.header is header:
            return self.template.with_data(numbers.copy())
        c = _clip_of(header, rows, frame_time, out)
        same = c.data.shape == numbers.shape and np.allclose(c.data, numbers, atol=1e-9)
        self.template, self.header = (c, header) if same else (None, None)
        return c


def _clip_of(header: list[str], rows: _Rows, frame_time: float | None, out: Path) -> Clip:
    """The take so far as a clip (read by the project's BVH reader, conventions and all)."""
    import os
    import tempfile

    from shared.io import load_clip

    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".partial-", suffix=".bvh", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            rows.write_bvh(f, header, frame_time)
        return load_clip(tmp)
    finally:
        Path(tmp).unlink(missing_ok=True)


