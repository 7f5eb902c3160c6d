"""A live trial's take, shared by `study run` and `coach live`: recorded by the capture service
from a live source until the expected repetitions are seen, cut into them, and the person at the
keyboard's redo or skip honoured on the way."""

from __future__ import annotations

import time
from pathlib import Path

import typer


class Controls:
    """What the person at the keyboard asks of a running `study run`: a line typed on its terminal
    (``r`` redo, ``s`` skip, ``q`` quit after this trial) or a command from another terminal
    (`study redo | skip | quit FOLDER`, which writes the word into ``FOLDER/.control``)."""

    WORDS = {"r": "redo", "s": "skip", "q": "quit", "redo": "redo", "skip": "skip", "quit": "quit"}

    def __init__(self, folder: Path):
        import queue
        import sys
        import threading

        self.file = folder / ".control"
        self.quit = False
        self.file.unlink(missing_ok=True)  # a word left from an earlier run is not this run's
        self.q: queue.Queue = queue.Queue()
        if sys.stdin is not None and sys.stdin.isatty():
            threading.Thread(target=self._keys, args=(sys.stdin,), daemon=True, name="study-keys").start()

    def _keys(self, stream) -> None:
        for line in stream:
            word = self.WORDS.get(line.strip().lower())
            if word:
                self.q.put(word)

    def next(self) -> str | None:
        """The next redo or skip asked for, if any (a quit is remembered in :attr:`quit`)."""
        import queue

        if self.file.exists():
            text = self.file.read_text(errors="replace")
            self.file.unlink(missing_ok=True)
            for word in text.split():
                if word.lower() in self.WORDS:
                    self.q.put(self.WORDS[word.lower()])
        while True:
            try:
                word = self.q.get_nowait()
            except queue.Empty:
                return None
            if word != "quit":
                return word
            self.quit = True


def _record(c, name: str, msg: dict, controls: Controls) -> tuple[dict, str | None]:
    """A take recorded by the capture service (``msg``: its record request): waits for it to end,
    watching for a word from the keyboard; (its final state, the word that ended it or None)."""
    import threading

    ended = threading.Event()
    c.subscribe("events/capture/take", lambda k, m: ended.set() if m.get("take") == name and m["state"] != "recording"
                else None)
    from shared.cli.common import ctrl_c_ends

    # Ctrl-C stops the take as well, then ends the run: the service would go on recording it (up to --seconds, from
    # a suit that streams on), and the run started again to record this trial would be refused ("is being recorded")
    with ctrl_c_ends("stopping the take, then the run") as interrupted:
        c.request("capture", "record", {**msg, "take": name, "replace": True})
        deadline = time.monotonic() + msg["seconds"] + msg["idle"] + 60
        polled = 0.0
        while time.monotonic() < deadline and not interrupted.is_set():
            word = controls.next()
            if word is not None:  # redo or skip
                c.request("capture", "stop", {"take": name})
                return c.request("capture", "status", {"take": name}), word
            ended.wait(0.05)
            if ended.is_set() or time.monotonic() - polled > 1.0:  # the event, or a slow poll if it was missed
                polled = time.monotonic()
                info = c.request("capture", "status", {"take": name})
                if info["state"] != "recording":
                    return info, None
        c.request("capture", "stop", {"take": name})
        if interrupted.is_set():
            raise KeyboardInterrupt
    return c.request("capture", "status", {"take": name}), None


def take_and_cut(c, prefix: str, msg: dict, controls: Controls, retries: int, echo) -> dict:
    """Takes named ``<prefix>_<k>`` recorded (``msg``: the capture service's record request, with
    its target and expected repetitions) until one holds a repetition, at most ``retries`` + 1
    (a take redone on request does not count). Returns {"word": "skip"} when skipped, else
    {"name", "info" (the take's state), "result" (the capture service's segment reply, None when
    no take held a repetition)}; ``echo(text)`` says what happened."""
    attempt = tries = 0
    info, result, name = None, None, None
    while tries <= retries:
        attempt += 1
        name = f"{prefix}_{attempt}"
        info, word = _record(c, name, msg, controls)
        for e in info["events"]:
            echo(f"  {e}")
        if word == "skip":
            return {"word": "skip"}
        if word == "redo":
            echo(f"  take {name}: redone on request")
            continue
        if info["state"] != "done":
            from shared.errors import Unavailable

            raise Unavailable(f"the take from {msg['source']} failed: {info.get('error', info['ended'])}")
        result = c.request("capture", "segment", {"take": name, "target": msg["target"], "expected": msg["expected"]})
        echo(f"  take {name}: {info['frames']} frames, {result['verdict']}")
        word = controls.next()
        if word == "skip":
            return {"word": "skip"}
        if word == "redo":
            echo(f"  take {name}: redone on request")
            result = None
            continue
        if result["repetitions"]:
            break
        tries += 1
        result = None
    return {"name": name, "info": info, "result": result}


def warm(clip) -> None:
    """Write ``clip`` once as BVH to a scratch file: the first BVH a process writes loads code that
    would otherwise delay the first trial's demonstration (0.4 s here)."""
    import tempfile

    from shared.io import save_clip

    if clip.skeleton is None:
        return
    with tempfile.TemporaryDirectory(prefix="mc-warm-") as d:
        save_clip(clip, Path(d) / "warm.bvh")


def save_take(c, name: str, path: Path) -> None:
    """A finished take fetched from the capture service and kept as a file."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    path.parent.mkdir(parents=True, exist_ok=True)
    save_clip(clip_from_wire(c.request("capture", "clip", {"take": name})["clip"]), path)


def ready_line(info: dict) -> str | None:
    """How long after the take's last frame the next demonstration and adverb were ready."""
    if info.get("last_frame_at") is None:
        return None
    now, now_unix = time.monotonic(), time.time()
    return (f"  next demonstration and adverb ready {now_unix - info['last_frame_at']:.2f} s after the take's last "
            f"frame ({info['ended_at'] - info['last_frame_at']:.2f} s of it until the take ended: {info['ended']}; "
            f"ready at {now:.3f})")


def say(adverb: str, path: Path, aloud: bool = False) -> None:
    """The adverb said into ``path`` and, with ``aloud``, through the speakers (a printed note,
    never a failure, without an engine or a player)."""
    from shared.capture.speech import NoSpeech, speak

    try:
        speech = speak(adverb, path, play=aloud)
        typer.echo(f"said \"{adverb}\" into {path} ({speech.seconds:.1f} s)" + (f"; {speech.note}" if speech.note else "")
                   + ("; played" if speech.played else ""), err=True)
    except NoSpeech as e:
        typer.echo(f"not said aloud: {e.message}", err=True)
