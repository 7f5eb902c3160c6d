"""The adverb said aloud (thesis ch. 4-5: the coach's adverb was spoken to the learner), with
the audio saved beside the session.

Text to speech is espeak-ng (a Debian package; ``make test`` installs it under CI). The speech is
written as a WAV file; :func:`say` plays it too when asked and a player is there (``aplay``), and
reports, never fails, when it cannot: the words are still printed and the file still saved.
"""

from __future__ import annotations

import shutil
import subprocess
import wave
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.errors import BadInput, MirrorcoachError

ENGINE = "espeak-ng"
TIMEOUT = 20.0  # seconds for the engine to speak one phrase


class NoSpeech(MirrorcoachError):
    code = "unavailable"


@dataclass
class Speech:
    path: Path
    seconds: float
    rms: float  # root mean square of the samples, 0-1: 0 is silence
    played: bool = False
    note: str = ""


def available() -> bool:
    return shutil.which(ENGINE) is not None


def speak(text: str, out: Path, *, voice: str = "en", play: bool = False) -> Speech:
    """Say ``text`` into the WAV file ``out`` (and aloud with ``play``)."""
    text = " ".join(str(text).split())
    if not text:
        raise BadInput("nothing to say")
    if len(text) > 500:
        raise BadInput(f"a phrase to say is at most 500 characters, got {len(text)}")
    engine = shutil.which(ENGINE)
    if engine is None:
        raise NoSpeech(f"no text-to-speech engine: install {ENGINE} (Debian package {ENGINE})")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        subprocess.run([engine, "-v", voice, "-w", str(out), "--", text], check=True, capture_output=True,
                       timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        raise NoSpeech(f"{ENGINE} did not finish saying {text!r} within {TIMEOUT:g} s") from None
    except subprocess.CalledProcessError as e:
        raise NoSpeech(f"{ENGINE} failed: {e.stderr.decode(errors='replace').strip()[:200]}") from None
    seconds, rms = measure(out)
    speech = Speech(out, seconds, rms)
    if play:
        player = shutil.which("aplay")
        if player is None:
            speech.note = "not played: no audio player (aplay) here; the speech is in the file"
        else:
            r = subprocess.run([player, "-q", str(out)], capture_output=True, timeout=TIMEOUT + seconds)
            speech.played = r.returncode == 0
            if not speech.played:
                speech.note = f"not played: {r.stderr.decode(errors='replace').strip()[:200]}"
    return speech


def measure(path: Path) -> tuple[float, float]:
    """A WAV file's duration (s) and loudness (RMS of its samples, 0-1)."""
    with wave.open(str(path)) as w:
        n, rate, width = w.getnframes(), w.getframerate(), w.getsampwidth()
        raw = w.readframes(n)
    if width != 2 or not n:
        return n / max(rate, 1), 0.0
    x = np.frombuffer(raw, "<i2").astype(float) / 32768.0
    return n / rate, float(np.sqrt(np.mean(x * x)))
