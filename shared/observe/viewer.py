"""The real rerun viewer, driven without a screen (DESIGN.md "Observability", measured recipe).

The viewer binary of the installed rerun (``rerun_cli/rerun``, not the Python wrapper, which
leaves it orphaned when killed) renders on the CPU with Mesa's Vulkan driver
(``apt-get install mesa-vulkan-drivers libvulkan1``): ``--headless --bind 127.0.0.1 --port P
--renderer vulkan --window-size WxH``. :class:`HeadlessViewer` starts it on a free loopback
port, waits until the recording has loaded, moves the time cursor, switches tabs, takes
screenshots and reads what each view reported; ``mirrorcoach dashboard --screenshot DIR`` and
the tests use it.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from pathlib import Path
from typing import Any

from shared.errors import BadInput, Unavailable

VULKAN_ICDS = (Path("/usr/share/vulkan/icd.d"), Path("/etc/vulkan/icd.d"))
RRD_MAGIC = b"RRF2"  # the first bytes of a rerun 0.41 recording file


def viewer_binary() -> Path:
    import rerun_cli

    return Path(rerun_cli.__file__).parent / "rerun"


def viewer_command(viewer: str, path) -> list[str]:
    """``make dashboard``'s viewer: on loopback only (it listens on 0.0.0.0 by default)
    and on a free port (on a taken port, ``rerun FILE`` sends the recording to whoever holds it)."""
    return [viewer, "--bind", "127.0.0.1", "--port", "auto", str(path)]


def why_no_viewer() -> str | None:
    """Why the viewer cannot run here (``None``: it can)."""
    try:
        exe = viewer_binary()
    except ImportError:
        return "rerun-sdk's viewer (rerun_cli) is not installed"
    if not exe.exists():
        return f"the rerun viewer binary is missing ({exe})"
    if not any(d.is_dir() and any(d.glob("*.json")) for d in VULKAN_ICDS):
        return ("no Vulkan driver: the headless viewer renders with Mesa's "
                "(`apt-get install mesa-vulkan-drivers libvulkan1`)")
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class HeadlessViewer:
    """``with HeadlessViewer(recording) as v: v.set_time("playback", 40); v.screenshot(path)``.

    ``recording``: an ``.rrd`` file, or ``None`` for a viewer that data is streamed to
    (``url`` is then the address to give ``MIRRORCOACH_RERUN_URL``)."""

    def __init__(self, recording=None, *, size: str = "1600x1000", log=None, timeout_s: float = 90.0):
        why = why_no_viewer()
        if why:
            raise Unavailable(f"the rerun viewer cannot run here: {why}", cause="no_viewer")
        self.recording = None if recording is None else Path(recording)
        self.size = size
        self.port = _free_port()
        self.url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        self.log = log
        self.timeout_s = timeout_s
        self.proc: subprocess.Popen | None = None
        self.client: Any = None  # rerun's viewer client once started

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> HeadlessViewer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        from rerun.experimental import ViewerClient

        args = [str(viewer_binary()), "--headless", "--bind", "127.0.0.1", "--port", str(self.port),
                "--renderer", "vulkan", "--window-size", self.size]
        if self.recording is not None:
            args.append(str(self.recording))
        if self.log:
            Path(self.log).parent.mkdir(parents=True, exist_ok=True)
        out = open(self.log, "ab") if self.log else subprocess.DEVNULL  # noqa: SIM115 (the viewer holds it)
        self.proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                     env={**os.environ, "RERUN_ANALYTICS": "0"})
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise Unavailable(f"the rerun viewer exited with {self.proc.returncode} before it answered"
                                  + (f" (its log: {self.log})" if self.log else ""), cause="no_viewer")
            try:
                self.client = ViewerClient.connect(self.url)
                self.client.get_state()
                return
            except Exception:  # not listening yet
                time.sleep(0.3)
        self.stop()
        raise Unavailable(f"the rerun viewer did not answer within {self.timeout_s:g} s", cause="timeout")

    def wait_loaded(self, settle_s: float = 8.0, timeout_s: float | None = None):
        """Until a recording with timelines is shown and nothing is loading; then ``settle_s``
        more for the viewer's start-up notices to fade. Returns the state."""
        deadline = time.monotonic() + (timeout_s or self.timeout_s)
        while time.monotonic() < deadline:
            st = self.client.get_state()
            if st.recordings and any(r.timelines for r in st.recordings) and not st.loading:
                time.sleep(settle_s)
                return self.client.get_state()
            time.sleep(0.3)
        raise Unavailable(f"the viewer did not load {self.recording or 'the stream'} within the time", cause="timeout")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(timeout=30)
        self.proc = None

    # ------------------------------------------------------------------ driving it
    def timelines(self) -> dict[str, tuple[int, int]]:
        st = self.client.get_state()
        rec = next((r for r in st.recordings if r.store_id == st.active_recording), st.recordings[0])
        return {t.name: (t.start, t.end) for t in rec.timelines}

    def set_time(self, timeline: str, value: int, settle_s: float = 1.5) -> None:
        """The time cursor on ``timeline`` (a sequence, or ``log_time`` in nanoseconds), paused."""
        if timeline == "log_time":
            self.client.set_time(timeline, timestamp=int(value) / 1e9, play_state="paused")
        else:
            self.client.set_time(timeline, sequence=int(value), play_state="paused")
        time.sleep(settle_s)

    def _tabs(self):
        """The blueprint as the viewer has it, and its tabs: ``{name: container key}`` in order."""
        info = self.client.get_blueprint()
        bp = info.blueprint
        tabs: dict = next((v["ContainerBlueprint"] for v in bp.values()
                     if v.get("ContainerBlueprint", {}).get("container_kind") == "Tabs"), {"contents": []})
        named = {}
        for c in tabs["contents"]:  # a tab is a container or a view of the blueprint, with a display name
            entry = bp.get(c if c.startswith("/") else "/" + c, {})
            label = next((part["display_name"] for part in entry.values() if "display_name" in part), None)
            if label is not None:
                named[label] = c
        return info, tabs, named

    def tabs(self) -> list[str]:
        """The names of the blueprint's tabs, in order."""
        return list(self._tabs()[2])

    def tab_views(self, name: str) -> list:
        """The views of the tab ``name`` (rerun's ``View``: ``view_id``, ``view_class``, ``name``,
        ``origin``), walking the blueprint's containers."""
        info, _, names = self._tabs()
        if name not in names:
            raise BadInput(f"the recording has no tab {name!r} (tabs: {', '.join(names)})")
        ids = set(_view_keys(info.blueprint, names[name]))
        return [v for v in self.views() if f"view/{v.view_id}" in ids]

    def tab_kinds(self) -> dict[str, tuple[str, str]]:
        """What each tab shows (:func:`tab_kind`: ``("session", id)``, ...), in order: ``{name: kind}``."""
        info, _, names = self._tabs()
        bp = info.blueprint
        return {name: tab_kind([bp["/" + k]["ViewBlueprint"].get("space_origin", "") for k in _view_keys(bp, key)])
                for name, key in names.items()}

    def show_tab(self, name: str, settle_s: float = 2.0) -> None:
        info, tabs, names = self._tabs()
        if name not in names:
            raise BadInput(f"the recording has no tab {name!r} (tabs: {', '.join(names)})")
        tabs["active_tab"] = names[name]
        self.client.set_blueprint(info.blueprint, store_id=info.store_id)
        time.sleep(settle_s)

    def views(self) -> list:
        return self.client.get_state().views

    def reports(self) -> list[tuple[str, str, str]]:
        """``(view, severity, summary)`` of every view that failed to visualize something."""
        return [(v.name, r.severity, r.summary) for v in self.views() for r in v.reports]

    def screenshot(self, path, view: str | None = None, origin: str | None = None) -> Path:
        """The whole viewer, or one view of the tab on screen, as a PNG: by name, and by its origin
        (the entity path it shows) where several tabs have a view of that name."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        view_id = None
        if view is not None or origin is not None:
            view_id = next(v.view_id for v in self.views()
                           if (view is None or v.name == view) and (origin is None or v.origin == origin))
        self.client.save_screenshot(str(path.absolute()), view_id=view_id)
        return path


def _view_keys(bp: dict, key: str):
    """The keys (``view/<id>``) of the views in the blueprint's container or view ``key``."""
    key = key.lstrip("/")
    entry = bp.get("/" + key, {})
    if "ContainerBlueprint" not in entry:
        yield key
        return
    contents = entry["ContainerBlueprint"].get("contents", [])
    for c in [contents] if isinstance(contents, str) else contents:
        yield from _view_keys(bp, c)


def tab_kind(origins: list[str]) -> tuple[str, str]:
    """What a tab of the dashboard shows, from its views' origins: ``("session", id)``,
    ``("estimate", id)`` or ``("other", "")``."""
    for o in origins:
        parts = o.strip("/").split("/")
        if len(parts) >= 2 and parts[0] in ("sessions", "estimates"):
            return parts[0][:-1], parts[1]
    return "other", ""


def dashboard_screenshots(recording, folder, log=None) -> list[Path]:
    """Every tab of a recording in the real viewer, on the timeline it opens on: a session's tab
    in the middle of its last trial (timeline ``playback``), the others as they open. Returns the
    PNG files (``session_<id>.png``, ``estimate_<id>.png``, or the tab's name)."""
    folder, recording = Path(folder), Path(recording)
    with open(recording, "rb") as f:  # before starting a viewer that would wait for it to load
        if f.read(4) != RRD_MAGIC:
            raise BadInput(f"{recording} is not a rerun recording (.rrd)")
    out = []
    with HeadlessViewer(recording, log=log) as v:
        v.wait_loaded()
        lines = v.timelines()
        if not v.tabs():  # a recording without this dashboard's blueprint: the viewer as it opens it
            return [v.screenshot(folder / "dashboard.png")]
        for tab, (kind, ident) in v.tab_kinds().items():
            v.show_tab(tab)
            if kind == "session" and "playback" in lines and "trial" in lines:
                n = lines["trial"][1]
                k = (lines["playback"][1] + 1) // (n + 1)
                v.set_time("playback", n * k + k // 2)
            name = f"{kind}_{ident}" if ident else tab
            out.append(v.screenshot(folder / ("".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name) + ".png")))
    return out
