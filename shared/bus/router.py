"""``python -m shared.bus.router``: the embedded Zenoh router (a router-mode session on the
loopback endpoint; no zenohd binary is needed). Runs until SIGTERM or SIGINT.

Deployed (``MIRRORCOACH_DEPLOY`` names a router identity) it listens with TLS and
mutual authentication and enforces the cluster's access control; every refusal is logged, one
line each (:class:`RefusalLog`): a message the access control denied (who, what, on which key)
and a TLS handshake that failed (no certificate, another CA, a wrong name).
"""

from __future__ import annotations

import logging
import os
import re
import signal
import sys
import threading

log = logging.getLogger("mirrorcoach.router")

#: Zenoh's own log filter on a deployed router: its access-control decisions (trace is the only
#: level at which Zenoh logs a denial) and TLS accept errors; RefusalLog keeps the refusals only
ZENOH_LOG = "warn,zenoh::net::routing::interceptor::access_control=trace,zenoh_link_tls=debug"
#: glibc's malloc arenas at most (``MALLOC_ARENA_MAX`` in the environment wins): with glibc's default
#: of 8 per core, Zenoh's threads spread client sessions' allocations over arenas that keep their
#: freed memory, and the router's resident memory climbed 41 -> 95 MB over 10,000 client sessions.
#: Measured with ``python -m bench.memory --bursts 20`` (4,000 sessions) and ``bench.bus``, two runs
#: of each setting alternated: the default 69 / 69 MB (20 concurrent recognitions 235 / 259 per s),
#: 4 arenas 56 / 55 MB (267 / 349 per s), 2 arenas 51 / 47 MB (188 / 273 per s), a 128 KB
#: ``MALLOC_MMAP_THRESHOLD_`` 77 / 77 MB: 4, the memory without a cost in throughput (those runs set
#: the environment; asked with ``mallopt`` at start since: 67 MB after 20,000 sessions, 62 before)
MALLOC_ARENAS = 4
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_DENIED = re.compile(r"CertCommonName\((?P<cn>[^)]*)\).* is unauthorized to (?P<what>.+?) \((?P<flow>ingress|egress)\) "
                     r"on (?P<key>\S+)")
_WHO = re.compile(r"(?P<zid>[0-9a-f]{8,32}) on \S*CertCommonName\((?P<cn>[^)]*)\)")
_CACHED = re.compile(r"Using cached result: (?P<zid>[0-9a-f]{8,32}) is unauthorized to (?P<what>.+?) "
                     r"\((?P<flow>ingress|egress)\) on (?P<key>\S+)")
_ACCEPTED = re.compile(r"Accepted TLS connection on \S+: \S+\. Common Name: (?P<cn>[^.\s][^\s]*?)\.?$")
_NO_SUBJECT = re.compile(r"(?P<zid>[0-9a-f]{8,32}) did not match any configured ACL subject")
_THREAD = re.compile(r"ThreadId\(\d+\)")
_CACHING = re.compile(r"caching permissions for `(?P<key>[^`]*)`")
_TLS_FAIL = re.compile(r"(?i)alert|handshake|certificate|invalid|unknown|error|fail")
_HINT = re.compile(r"\s*Hint: increase the system open file limit\.?")  # Zenoh's hint on every TLS error


class RefusalLog:
    """Reads what Zenoh's Rust logger writes (to stdout, fd 1, here through a pipe) and keeps, on
    stderr: warnings and errors; each access-control refusal as ``REFUSED <common name> may not
    <what> (<flow>) on <key>`` (also a decision Zenoh logs by session id only, after it cached a
    key's permissions: the name comes from the session's earlier lines); a certificate of the CA
    whose name is in no role (``REFUSED <name>: ... in no role``); and failed TLS handshakes as
    ``REFUSED a TLS connection: ...``. The rest (Zenoh's trace of every *allowed* decision) is
    dropped, so the log stays small."""

    def __init__(self) -> None:
        self.out = os.fdopen(os.dup(2), "w", buffering=1)
        self._seen: dict[tuple, int] = {}
        self._caching: dict[str, str] = {}  # thread -> the key whose permissions it is caching
        self._names: dict[str, str] = {}  # a session's id -> its certificate's common name
        self._accepted: dict[str, str] = {}  # thread -> the common name of the TLS link it just accepted
        r, w = os.pipe()
        os.dup2(w, 1)
        os.close(w)
        self._r = r
        threading.Thread(target=self._pump, name="refusal-log", daemon=True).start()

    def _pump(self) -> None:
        with os.fdopen(self._r, "r", errors="replace") as f:
            for raw in f:
                line = _ANSI.sub("", raw).rstrip()
                self.keep(line)

    def keep(self, line: str) -> None:
        found = _THREAD.search(line)
        thread = found.group(0) if found else ""
        who = _WHO.search(line)
        if who:  # a session's id and its certificate's name, for the decisions that give the id only
            self._names[who["zid"]] = who["cn"]
            if len(self._names) > 10_000:  # sessions come and go: the oldest names are forgotten
                for zid in list(self._names)[:5_000]:
                    del self._names[zid]
        accepted = _ACCEPTED.search(line)
        if accepted:  # the access control's next line on this thread is about this certificate
            self._accepted[thread] = accepted["cn"]
            return
        c = _CACHING.search(line)
        if c:  # this thread then evaluates every kind of message on that key once: not decisions
            self._caching[thread] = c["key"]
            return
        if " is authorized to " in line:  # allowed: nothing to log (a caching block goes on)
            return
        nobody = _NO_SUBJECT.search(line)
        if nobody:  # signed by the cluster's CA, but in no role of the access control
            cn = self._accepted.pop(thread, None) or "?"
            self._names[nobody["zid"]] = cn
            self._refused(line, (cn, "subject"), f"{cn}: a certificate of this cluster's CA whose name is in no role "
                                                 "of the access control; every message of it is denied")
            return
        m = _DENIED.search(line)
        if m and m["key"] == self._caching.get(thread) and "cached result" not in line:
            return
        self._caching.pop(thread, None)
        cached = None if m else _CACHED.search(line)
        if cached:  # the decision itself, after a caching block: the name from the session's id
            m, cn = cached, self._names.get(cached["zid"], cached["zid"][:8])
        elif m:
            cn = m["cn"] or "?"
        if m:
            self._refused(line, (cn, m["what"], m["flow"], m["key"]),
                          f"{cn} may not {m['what']} ({m['flow']}) on {m['key']}")
            return
        if "zenoh_link_tls" in line and "Accepted TLS connection" not in line and _TLS_FAIL.search(line):
            what = _HINT.sub("", line.split("zenoh_link_tls::unicast:", 1)[-1]).strip()
            self.out.write(f"{line[:27]} router REFUSED a TLS connection: {what}\n")
        elif " WARN " in line or " ERROR " in line:
            self.out.write(line + "\n")

    def _refused(self, line: str, key: tuple, text: str) -> None:
        """One line per refusal; a flood of one refusal is counted, so it cannot fill the disk."""
        n = self._seen[key] = self._seen.get(key, 0) + 1
        if n <= 20 or n % 1000 == 0:
            self.out.write(f"{line[:27]} router REFUSED {text}" + (f" ({n} times)" if n > 20 else "") + "\n")
        if len(self._seen) > 10_000:  # refusals on ever new keys: the counts start again
            self._seen.clear()


def limit_malloc_arenas(n: int = MALLOC_ARENAS) -> str:
    """Ask the C library for at most ``n`` malloc arenas (glibc's ``mallopt``; before Zenoh's
    threads start, which make the arenas), unless the environment says how many; what was done."""
    if os.environ.get("MALLOC_ARENA_MAX"):
        return f"malloc arenas as MALLOC_ARENA_MAX says ({os.environ['MALLOC_ARENA_MAX']})"
    from shared.bus.budget import M_ARENA_MAX, mallopt

    return f"malloc arenas at most {n}" if mallopt(M_ARENA_MAX, n) else "malloc arenas as the C library makes them (no mallopt)"


def main() -> int:
    arenas = limit_malloc_arenas()
    import zenoh

    from shared.bus.config import Settings, prepare_socket, router_config, socket_path
    from shared.errors import BadInput, MirrorcoachError

    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s router %(levelname)s %(message)s")
    try:
        settings = Settings()
        config = router_config(settings)
    except MirrorcoachError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return 2
    if settings.identity is not None:
        RefusalLog()
        zenoh.init_log_from_env_or(ZENOH_LOG)
    sock = socket_path(settings.router) if settings.identity is None else None
    if sock is not None:
        try:
            prepare_socket(sock)
        except (BadInput, OSError) as e:
            print(f"error: cannot listen on {settings.router}: {getattr(e, 'message', e)}", file=sys.stderr)
            return 2
        os.umask(0o077)  # the socket file is its user's alone (0600)
    try:
        session = zenoh.open(config)
    except zenoh.ZError as e:
        if settings.identity is not None:
            log.error("cannot listen on %s: %s", settings.router, e)
        print(f"error: cannot listen on {settings.router}: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    where = ", ".join(settings.identity.listen or []) + " (TLS, access control)" if settings.identity else settings.router
    log.info("router listening on %s; %s", where, arenas)
    while not stop.wait(0.5):
        pass
    session.close()
    log.info("router stopped")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
