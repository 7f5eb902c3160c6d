"""Where the cluster lives: endpoints, key prefix, data folder, limits (environment variables).

================================  ==========================  ===========================================
variable                          default                     meaning
================================  ==========================  ===========================================
``MIRRORCOACH_ROUTER``            a socket in the home        the router's endpoint: by default the Unix
                                                              socket ``<home>/run/router.sock`` (its
                                                              user's alone); or ``tcp/127.0.0.1:PORT``
                                                              (loopback only, open to every local user)
``MIRRORCOACH_PREFIX``            ``mc``                      first segment of every key
``MIRRORCOACH_HOME``              ``./var``                   data (``data/<service>``), logs, pid files
``MIRRORCOACH_MAX_PAYLOAD``       ``67108864`` (64 MiB)       largest request a service accepts, bytes
``MIRRORCOACH_TIMEOUT``           ``120``                     default request timeout of the CLI, seconds;
                                                              extended to a verb's own time limit when
                                                              its contract allows longer work (past it,
                                                              the client looks every 2 s that the
                                                              service is still there to answer)
``MIRRORCOACH_WORKERS``           ``4``                       requests a service handles at once (more
                                                              threads than cores only fight for the GIL)
``MIRRORCOACH_QUEUE``             ``256``                     requests a service keeps waiting beyond its
                                                              workers; more get ``unavailable`` at once
``MIRRORCOACH_QUEUE_MB``          ``512``                     bytes of waiting requests a service keeps
                                                              (one request is always taken when idle)
``MIRRORCOACH_MEMORY_MB``         ``1536``                    memory of one service process (below the
                                                              unit's MemoryMax=2G and the compose limit):
                                                              requests run while their estimated working
                                                              memory fits beside what the service holds,
                                                              wait for it, or are refused when it never
                                                              can (``shared/bus/budget.py``)
``MIRRORCOACH_WAITING``           ``32``                      questions to people a service keeps open at
                                                              once (verbs that wait, on their own pool)
``MIRRORCOACH_TIME_LIMIT``        ``600``                     seconds any request may run (each verb declares
                                                              its own limit, at most this); past it the
                                                              request stops at a safe point: ``unavailable``
``MIRRORCOACH_RECORDING_MB``      ``64``                      the observer starts a new recording when
                                                              its file passes this size (at least 2: the
                                                              layout of 16 sessions alone takes ~1 MB)
``MIRRORCOACH_RECORDINGS``        ``10``                      recordings kept (the oldest are deleted)
``MIRRORCOACH_OBSERVER_QUEUE_MB`` ``256``                     events waiting for the observer; more are
                                                              dropped (counted in its log)
``MIRRORCOACH_DEPLOY``            (unset)                     a deployed cluster across hosts: this
                                                              process's identity folder from `mirrorcoach
                                                              deploy init` (TLS, access control, routers);
                                                              see shared/bus/deploy.py
================================  ==========================  ===========================================

The embedded default topology (DESIGN.md "Bus conventions"): one router-mode Zenoh session
listening on a Unix socket in the cluster's home, every service and the CLI as clients connecting
to it, multicast and gossip scouting off, so nothing binds a network port. The home is 0700 and
the socket 0600, so another user of the machine can neither reach the socket nor connect to it:
a TCP port on 127.0.0.1 (``MIRRORCOACH_ROUTER=tcp/127.0.0.1:PORT``, as the tests and benchmarks
use) is open to every local user, who could then call, answer in a service's place or listen.
A home whose socket path would pass the system's limit (107 bytes) gets its socket in
``/tmp/mirrorcoach-<uid>/`` (0700) instead, named after the home.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from shared.bus.codec import DEFAULT_MAX_PAYLOAD
from shared.errors import BadInput

if TYPE_CHECKING:  # annotations only: deploy reads identities with this module's settings
    from shared.bus.deploy import Identity

LOOPBACK_HOSTS = {"localhost"}


def _env(name: str, default: str) -> str:
    v = os.environ.get(name, "").strip()
    return v or default


def _env_num(name: str, default, kind=int):
    raw = _env(name, str(default))
    try:
        return kind(raw)
    except ValueError:
        raise BadInput(f"{name}={raw!r} is not a number") from None


SOCKET = "unixsock-stream/"
MAX_SOCKET_PATH = 107  # bytes of a Unix socket's path (sun_path, with its terminating zero)


def socket_path(endpoint: str) -> Path | None:
    """The socket file of a ``unixsock-stream/PATH`` endpoint, or None for any other."""
    return Path(endpoint[len(SOCKET):]) if endpoint.startswith(SOCKET) else None


def default_router(home: Path) -> str:
    """The cluster's own socket: ``<home>/run/router.sock``, or, where that path is too long for a
    socket, one in ``/tmp/mirrorcoach-<uid>`` named after the home."""
    import hashlib

    path = home / "run" / "router.sock"
    if len(os.fsencode(str(path))) > MAX_SOCKET_PATH:
        digest = hashlib.sha256(os.fsencode(str(home))).hexdigest()[:16]
        path = Path(f"/tmp/mirrorcoach-{os.getuid()}") / f"{digest}.sock"
    return f"{SOCKET}{path}"


def socket_in_use(path: Path) -> bool:
    """Whether a process listens on the socket file ``path`` (a file left by a router killed
    with SIGKILL is not in use)."""
    import socket

    if not path.exists():
        return False
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(1.0)
        try:
            sock.connect(str(path))
            return True
        except OSError:
            return False


def prepare_socket(path: Path) -> None:
    """The folder of the router's socket made the user's alone (0700, refused when another user
    owns it), and a socket file left by a killed router removed."""
    folder = path.parent
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    st = folder.stat()
    if st.st_uid != os.getuid():
        raise BadInput(f"the router's socket folder {folder} belongs to another user: not safe to listen there")
    folder.chmod(0o700)
    if path.exists() and not socket_in_use(path):
        path.unlink()


def parse_endpoint(endpoint: str) -> tuple[str, str, int]:
    """``tcp/127.0.0.1:7447`` -> ``("tcp", "127.0.0.1", 7447)`` (``[::1]`` without brackets)."""
    m = re.fullmatch(r"(tcp|udp)/\[?([^\]]+?)\]?:(\d{1,5})", endpoint)
    if not m:
        raise BadInput(f"endpoint {endpoint!r} is not of the form tcp/127.0.0.1:PORT")
    return m.group(1), m.group(2), int(m.group(3))


def check_loopback(endpoint: str) -> str:
    """``tcp/127.0.0.1:7447`` or ``unixsock-stream/ABSOLUTE_PATH`` -> itself; anything not on this
    machine is refused."""
    path = socket_path(endpoint)
    if path is not None:
        if not path.is_absolute() or len(os.fsencode(str(path))) > MAX_SOCKET_PATH:
            raise BadInput(f"endpoint {endpoint!r}: a socket needs an absolute path of at most {MAX_SOCKET_PATH} bytes")
        return endpoint
    _, host, port = parse_endpoint(endpoint)
    if not 0 < port < 65536:
        raise BadInput(f"endpoint {endpoint!r}: port out of range")
    if host not in LOOPBACK_HOSTS:
        try:
            if not ipaddress.ip_address(host).is_loopback:
                raise ValueError
        except ValueError:
            raise BadInput(f"endpoint {endpoint!r} is not a loopback address; the embedded cluster binds 127.0.0.1 only") from None
    return endpoint


@dataclass
class Settings:
    router: str = field(default_factory=lambda: _env("MIRRORCOACH_ROUTER", ""))  # "": the home's socket
    prefix: str = field(default_factory=lambda: _env("MIRRORCOACH_PREFIX", "mc"))
    home: Path = field(default_factory=lambda: Path(_env("MIRRORCOACH_HOME", "var")).absolute())
    max_payload: int = field(default_factory=lambda: _env_num("MIRRORCOACH_MAX_PAYLOAD", DEFAULT_MAX_PAYLOAD))
    timeout: float = field(default_factory=lambda: _env_num("MIRRORCOACH_TIMEOUT", 120.0, float))
    workers: int = field(default_factory=lambda: _env_num("MIRRORCOACH_WORKERS", 4))
    queue: int = field(default_factory=lambda: _env_num("MIRRORCOACH_QUEUE", 256))
    memory_mb: float = field(default_factory=lambda: _env_num("MIRRORCOACH_MEMORY_MB", 1536.0, float))
    queue_mb: float = field(default_factory=lambda: _env_num("MIRRORCOACH_QUEUE_MB", 512.0, float))
    waiting: int = field(default_factory=lambda: _env_num("MIRRORCOACH_WAITING", 32))
    time_limit: float = field(default_factory=lambda: _env_num("MIRRORCOACH_TIME_LIMIT", 600.0, float))
    recording_mb: float = field(default_factory=lambda: _env_num("MIRRORCOACH_RECORDING_MB", 64.0, float))
    recordings: int = field(default_factory=lambda: _env_num("MIRRORCOACH_RECORDINGS", 10))
    observer_queue_mb: float = field(default_factory=lambda: _env_num("MIRRORCOACH_OBSERVER_QUEUE_MB", 256.0, float))
    deploy: Path | None = field(default_factory=lambda: Path(_env("MIRRORCOACH_DEPLOY", "")) if _env(
        "MIRRORCOACH_DEPLOY", "") else None)
    identity: Identity | None = None  # when deployed

    def __post_init__(self):
        if self.deploy is not None:  # several hosts: TLS and the identity's routers, never the loopback default
            from shared.bus.deploy import load_identity

            self.identity = load_identity(self.deploy)
            if os.environ.get("MIRRORCOACH_PREFIX", "").strip() not in ("", self.identity.prefix):
                raise BadInput(f"MIRRORCOACH_PREFIX={os.environ['MIRRORCOACH_PREFIX']} but the deployed identity's "
                               f"prefix is {self.identity.prefix!r}; unset one")
            self.prefix, self.router = self.identity.prefix, ", ".join(self.identity.routers)
        else:
            self.router = self.router or default_router(self.home)
            check_loopback(self.router)
        if not 1 <= self.workers <= 64:
            raise BadInput(f"MIRRORCOACH_WORKERS must be 1..64, got {self.workers}")
        if not 1 <= self.waiting <= 1000:
            raise BadInput(f"MIRRORCOACH_WAITING must be 1..1000, got {self.waiting}")
        if not 0 <= self.queue <= 100_000 or not 0 < self.queue_mb <= 1e6:
            raise BadInput(f"MIRRORCOACH_QUEUE must be 0..100000 and MIRRORCOACH_QUEUE_MB positive, "
                           f"got {self.queue} and {self.queue_mb}")
        if not 128 <= self.memory_mb <= 1e7:
            raise BadInput(f"MIRRORCOACH_MEMORY_MB must be 128..10000000 (MB per service process), "
                           f"got {self.memory_mb}")
        if not 0 < self.time_limit <= 1e6:
            raise BadInput(f"MIRRORCOACH_TIME_LIMIT must be positive seconds, got {self.time_limit}")
        if not (2 <= self.recording_mb <= 1e6 and 1 <= self.recordings <= 10_000 and 0 < self.observer_queue_mb <= 1e6):
            raise BadInput(f"MIRRORCOACH_RECORDING_MB must be at least 2 (a dashboard's layout takes up to ~1 MB), "
                           f"MIRRORCOACH_OBSERVER_QUEUE_MB positive and MIRRORCOACH_RECORDINGS 1..10000, got "
                           f"{self.recording_mb}, {self.observer_queue_mb} and "
                           f"{self.recordings}")
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,32}", self.prefix):
            raise BadInput(f"MIRRORCOACH_PREFIX {self.prefix!r} must be 1-32 letters, digits, '_' or '-'")

    def key(self, *parts: str) -> str:
        return "/".join((self.prefix, *parts))

    def data_dir(self, service: str) -> Path:
        return self.home / "data" / service

    @property
    def log_dir(self) -> Path:
        return self.home / "logs"

    @property
    def run_dir(self) -> Path:
        return self.home / "run"


def max_message_size(s: Settings) -> int:
    """The largest Zenoh message any session of the cluster reassembles: the largest request a
    service accepts plus room for the key and attachments. Zenoh's default is 1 GiB, so a 600 MiB
    request was reassembled whole by the router and the service before the 64 MiB check;
    now the router drops it after 64 MiB of fragments."""
    return s.max_payload + (1 << 20)


def _base(mode: str, s: Settings):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("adminspace/enabled", "false")
    # Zenoh's shared memory is on by default: every session that sent a message above 3 KB kept
    # a 16 MiB pool in /dev/shm, freed only when the process ended (7.4 GB after two bursts of
    # 200 clients). Messages between processes on one host are small next to
    # the work they ask for (bench/results/bus.md), so the copy through TCP costs little.
    c.insert_json5("transport/shared_memory/enabled", "false")
    c.insert_json5("transport/link/rx/max_message_size", str(max_message_size(s)))
    return c


def router_config(s: Settings):
    """The router: listens on the loopback endpoint and nowhere else (deployed: its identity's
    Zenoh config, TLS and access control)."""
    if s.identity is not None:
        from shared.bus.deploy import load_config

        if s.identity.role != "router":
            raise BadInput(f"MIRRORCOACH_DEPLOY={s.deploy} is the identity of a {s.identity.role}, not of a router")
        c = load_config(s.identity)
        c.insert_json5("transport/link/rx/max_message_size", str(max_message_size(s)))
        return c
    c = _base("router", s)
    c.insert_json5("listen/endpoints", json.dumps([s.router]))
    return c


def client_config(s: Settings, wait: bool = True, connect_timeout_s: float = 3.0):
    """A client of the router. Services wait for it forever (start order does not matter);
    the CLI gives up after ``connect_timeout_s`` with a clear message. Deployed: the identity's
    Zenoh config (TLS with its own certificate, every router of the cluster)."""
    if s.identity is not None:
        from shared.bus.deploy import load_config

        c = load_config(s.identity)
        c.insert_json5("transport/link/rx/max_message_size", str(max_message_size(s)))
    else:
        c = _base("client", s)
        c.insert_json5("listen/endpoints", "[]")
        c.insert_json5("connect/endpoints", json.dumps([s.router]))
    c.insert_json5("connect/timeout_ms", "-1" if wait else str(int(connect_timeout_s * 1000)))
    c.insert_json5("connect/exit_on_failure", "false" if wait else "true")
    return c
