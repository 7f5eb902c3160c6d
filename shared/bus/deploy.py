"""A cluster across several hosts, secured: certificates, access control, Zenoh configs.

``mirrorcoach deploy init OUT`` writes, for a cluster whose router(s) live at given addresses:

* ``OUT/ca/``: a small certificate authority (``ca.pem``, and ``ca.key``, which stays with the
  operator and is never copied to a host);
* ``OUT/<identity>/`` for every **identity** (one per service instance, per client, per
  router): ``cert.pem`` and ``key.pem`` (its own key pair, EC P-256, the certificate's common
  name is ``<name>.<role>``, :func:`cert_name`), ``ca.pem``, ``identity.json`` (name, role, prefix, routers) and
  ``zenoh.json5``, the complete Zenoh config of that process.

Point a process at its folder with ``MIRRORCOACH_DEPLOY=OUT/<identity>``; nothing else changes.

Security, when on (it is off on the loopback default, which stays as it was):

* every link is TLS with **mutual authentication** (``transport.link.tls``, ``enable_mtls``,
  ``protocols: ["tls"]``): a process without a certificate of this CA cannot open a session;
* the router enforces Zenoh's ``access_control`` (default ``deny``) with one subject per
  **role**, matched by ``cert_common_names``; a certificate's common name carries its role
  (``pss-a.pss``, ``alice.cli``), so no name an operator chooses can carry another role's
  rights. What each role may do (:data:`ROLES`):

  ======================  =======================================================================
  role                    may
  ======================  =======================================================================
  a service (pss, ...)    serve ``<prefix>/<service>/*`` (queryable, replies), publish
                          ``<prefix>/events/<service>/**``, declare ``<prefix>/alive/<service>``
                          and ``<prefix>/leader/<service>/*``, and call every service
  ``cli``                 call every service and read liveliness and events; never serve,
                          never publish
  ``dashboard``           subscribe to ``<prefix>/events/**`` and declare
                          ``<prefix>/alive/observer``; nothing else
  ``router``              another router of the same cluster (router-to-router links)
  ======================  =======================================================================

The router logs every refused message (Zenoh's access-control interceptor at ``debug``, see
:func:`router_log_filter`) and every refused TLS handshake.
"""

from __future__ import annotations

import datetime as _dt
import ipaddress
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shared.errors import BadInput

SERVICES = ("pss", "simulator", "coach", "dialogue", "estimator", "capture")
ROLES = SERVICES + ("cli", "dashboard", "router")
#: the roles an identity of ``--identity`` may take (a router's is made by ``--router``)
IDENTITY_ROLES = tuple(r for r in ROLES if r != "router")
DEFAULT_PORT = 7447
NAME_RE = re.compile(r"[a-z][a-z0-9-]{0,40}")
#: link lease (ms): how long a router waits before declaring a silent peer gone. Zenoh's default is
#: 10 s; 3 s lets a standby take over within a few seconds of a host's link being cut.
DEFAULT_LEASE_MS = 3000
CERT_FILES = ("cert.pem", "key.pem", "ca.pem")


@dataclass
class Identity:
    """One process's place in a deployed cluster (``identity.json``)."""

    name: str  # the identity's name (its certificate's common name is cert_name(name, role))
    role: str  # one of ROLES
    prefix: str
    routers: list[str]  # tls/ADDR:PORT endpoints of the cluster's routers
    folder: Path
    listen: list[str] | None = None  # routers only

    @property
    def service(self) -> str | None:
        return self.role if self.role in SERVICES else None


def cert_name(name: str, role: str) -> str:
    """The common name of an identity's certificate, ``<name>.<role>``: the access control matches
    it, so the role is bound in the certificate; a name alone (``router``) carries no rights."""
    return f"{name}.{role}"


def check_name(name: str, what: str = "identity") -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise BadInput(f"{what} name {name!r} must be 1-41 lowercase letters, digits or '-', starting with a letter",
                       field=what)
    return name


def parse_router(spec: str) -> tuple[str, str, int]:
    """``NAME=ADDR[:PORT]`` -> (name, addr, port); ADDR an IP address or a host name."""
    m = re.fullmatch(r"([^=]+)=\[?([A-Za-z0-9.:-]+?)\]?(?::(\d{1,5}))?", spec.strip())
    if not m:
        raise BadInput(f"router {spec!r} is not NAME=ADDRESS[:PORT] (e.g. router=10.0.0.1:7447)", field="router")
    port = int(m.group(3) or DEFAULT_PORT)
    if not 0 < port < 65536:
        raise BadInput(f"router {spec!r}: port out of range", field="router")
    return check_name(m.group(1), "router"), m.group(2), port


def parse_identity(spec: str) -> tuple[str, str]:
    """``NAME:ROLE`` or ``ROLE`` (the name is then the role) -> (name, role)."""
    name, _, role = spec.partition(":")
    role = role or name
    if role not in IDENTITY_ROLES:
        raise BadInput(f"identity {spec!r}: role must be one of {', '.join(IDENTITY_ROLES)}", field="identity")
    return check_name(name), role


def _endpoint(addr: str, port: int) -> str:
    try:
        if ipaddress.ip_address(addr).version == 6:
            return f"tls/[{addr}]:{port}"
    except ValueError:
        pass
    return f"tls/{addr}:{port}"


# ---------------------------------------------------------------------------------- certificates
def _now():
    return _dt.datetime.now(_dt.UTC)


def make_ca(days: int, cn: str = "mirrorcoach cluster CA"):
    """A self-signed CA: (key, certificate)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(_now() - _dt.timedelta(minutes=5))
            .not_valid_after(_now() + _dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


def issue(ca_key, ca_cert, cn: str, hosts: list[str], days: int, role: str | None = None):
    """A leaf certificate for ``cn`` (client and server use), valid for ``hosts`` (SANs); its
    subject also names ``role`` (organizational unit), for a person reading it."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    sans: list[x509.GeneralName] = []
    for h in dict.fromkeys([cn, *hosts]):
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    subject = [x509.NameAttribute(NameOID.COMMON_NAME, cn)]
    if role is not None:
        subject.append(x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role))
    cert = (x509.CertificateBuilder().subject_name(x509.Name(subject))
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(_now() - _dt.timedelta(minutes=5)).not_valid_after(_now() + _dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=False, crl_sign=False,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def _pem(obj) -> bytes:
    from cryptography.hazmat.primitives import serialization

    if hasattr(obj, "private_bytes"):
        return obj.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                 serialization.NoEncryption())
    return obj.public_bytes(serialization.Encoding.PEM)


def _write(path: Path, data: bytes, private: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


# ---------------------------------------------------------------------------------- access control
def acl(prefix: str, members: dict[str, list[str]]) -> dict:
    """Zenoh's ``access_control`` section: ``members`` maps a role to the common names of its
    identities (module docstring's table). Default deny; every allowed message listed."""
    p = prefix
    rules: list[dict] = []
    subjects: list[dict] = []
    policies: list[dict] = []

    def rule(rid: str, messages: list[str], keys: list[str], flows=("ingress", "egress")):
        if any(r["id"] == rid for r in rules):
            return rid
        rules.append({"id": rid, "messages": messages, "flows": list(flows), "permission": "allow", "key_exprs": keys})
        return rid

    # every role: the replies it is sent, liveliness it reads
    call = rule("call", ["query"], [f"{p}/*/*"], ("ingress",))
    replies = rule("replies", ["reply"], [f"{p}/*/*"], ("egress",))
    alive = [rule("alive-ask", ["liveliness_query", "declare_liveliness_subscriber"], [f"{p}/alive/*", f"{p}/leader/**"],
                  ("ingress",)),
             rule("alive-hear", ["liveliness_token"], [f"{p}/alive/*", f"{p}/leader/**"], ("egress",))]
    events = [rule("events-subscribe", ["declare_subscriber"], [f"{p}/events/**"], ("ingress",)),
              rule("events-deliver", ["put"], [f"{p}/events/**"], ("egress",))]
    for role, names in members.items():
        if not names:
            continue
        subjects.append({"id": role, "cert_common_names": sorted(names)})
        if role in SERVICES:
            own = [rule(f"{role}-serve", ["declare_queryable", "query", "reply"], [f"{p}/{role}/*"]),
                   rule(f"{role}-publish", ["put"], [f"{p}/events/{role}/**"], ("ingress",)),
                   rule("listeners", ["declare_subscriber"], [f"{p}/events/**"], ("egress",)),  # who listens
                   rule(f"{role}-alive", ["liveliness_token"], [f"{p}/alive/{role}", f"{p}/leader/{role}/*"],
                        ("ingress",))]
            policies.append({"id": f"{role}-policy", "subjects": [role], "rules": [*own, call, replies, *alive, *events]})
        elif role == "cli":
            policies.append({"id": "cli-policy", "subjects": [role], "rules": [call, replies, *alive, *events]})
        elif role == "dashboard":
            token = rule("dashboard-alive", ["liveliness_token"], [f"{p}/alive/observer"], ("ingress",))
            policies.append({"id": "dashboard-policy", "subjects": [role], "rules": [*events, token]})
        elif role == "router":
            every = rule("router-all", ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                                        "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"],
                         [f"{p}/**"])
            policies.append({"id": "router-policy", "subjects": [role], "rules": [every]})
    # a rule used by no policy would be refused by Zenoh: keep the used ones only, once each
    used = {r for pol in policies for r in pol["rules"]}
    rules = [r for r in rules if r["id"] in used]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def router_log_filter() -> str:
    """``RUST_LOG``-style filter for a deployed router: warnings, plus Zenoh's access-control and
    TLS messages, so that every refusal is logged."""
    return "warn,zenoh::net::routing::interceptor=debug,zenoh_link_tls=debug,zenoh_transport=info"


# ---------------------------------------------------------------------------------- zenoh configs
def zenoh_config(ident: Identity, max_message_size: int, lease_ms: int, acl_section: dict | None) -> dict:
    """The Zenoh config of one identity (cert paths relative to its folder; :func:`load_config`
    resolves them)."""
    tls = {"root_ca_certificate": "ca.pem", "enable_mtls": True, "verify_name_on_connect": True,
           "connect_private_key": "key.pem", "connect_certificate": "cert.pem"}
    cfg: dict[str, Any] = {
        "mode": "router" if ident.role == "router" else "client",
        # a router links to the cluster's other routers; everyone else to every router
        "connect": {"endpoints": [e for e in ident.routers if e not in (ident.listen or [])]},
        "listen": {"endpoints": list(ident.listen or [])},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "adminspace": {"enabled": False},
        "transport": {
            "shared_memory": {"enabled": False},
            "link": {"protocols": ["tls"], "tls": tls, "rx": {"max_message_size": max_message_size},
                     "tx": {"lease": lease_ms}},
        },
    }
    if ident.role == "router":
        tls.update({"listen_private_key": "key.pem", "listen_certificate": "cert.pem"})
        cfg["access_control"] = acl_section
    return cfg


def load_identity(folder) -> Identity:
    """``MIRRORCOACH_DEPLOY``'s folder -> :class:`Identity`, with a clear error when incomplete."""
    folder = Path(folder).expanduser().absolute()
    meta = folder / "identity.json"
    try:
        d = json.loads(meta.read_text())
    except FileNotFoundError:
        raise BadInput(f"MIRRORCOACH_DEPLOY={folder}: no identity.json there (make one with `mirrorcoach deploy init`)",
                       field="MIRRORCOACH_DEPLOY") from None
    except (OSError, ValueError) as e:
        raise BadInput(f"{meta}: unreadable ({e})", field="MIRRORCOACH_DEPLOY") from None
    for f in (*CERT_FILES, "zenoh.json5"):
        if not (folder / f).is_file():
            raise BadInput(f"MIRRORCOACH_DEPLOY={folder}: {f} is missing", field="MIRRORCOACH_DEPLOY")
    try:
        ident = Identity(name=d["name"], role=d["role"], prefix=d["prefix"], routers=list(d["routers"]), folder=folder,
                         listen=d.get("listen"))
    except (KeyError, TypeError):
        raise BadInput(f"{meta}: needs name, role, prefix and routers", field="MIRRORCOACH_DEPLOY") from None
    if ident.role not in ROLES:
        raise BadInput(f"{meta}: unknown role {ident.role!r}", field="MIRRORCOACH_DEPLOY")
    return ident


def load_config(ident: Identity):
    """The identity's ``zenoh.json5`` as a ``zenoh.Config``, its certificate paths made absolute."""
    import zenoh

    text = (ident.folder / "zenoh.json5").read_text()
    try:
        cfg = json.loads(text)
    except ValueError as e:
        raise BadInput(f"{ident.folder / 'zenoh.json5'}: not JSON ({e})", field="MIRRORCOACH_DEPLOY") from None
    tls = cfg.get("transport", {}).get("link", {}).get("tls", {})
    for k, v in list(tls.items()):
        if isinstance(v, str) and v.endswith(".pem") and not os.path.isabs(v):
            tls[k] = str(ident.folder / v)
    try:
        return zenoh.Config.from_json5(json.dumps(cfg))
    except zenoh.ZError as e:
        raise BadInput(f"{ident.folder / 'zenoh.json5'}: Zenoh refused it ({e})", field="MIRRORCOACH_DEPLOY") from None


def init(out, routers: list[str], identities: list[str], prefix: str = "mc", days: int = 825,
         lease_ms: int = DEFAULT_LEASE_MS, max_message_size: int | None = None, ca_from=None) -> dict:
    """Make the CA (or reuse ``ca_from``'s), every identity's key, certificate and Zenoh config.

    ``routers``: ``NAME=ADDR[:PORT]`` (each router listens on its address); ``identities``:
    ``NAME:ROLE`` (or just ``ROLE``). Returns ``{name: role}``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    from shared.bus.codec import DEFAULT_MAX_PAYLOAD

    out = Path(out)
    if not routers:
        raise BadInput("give at least one router: --router NAME=ADDRESS[:PORT]", field="router")
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,32}", prefix):
        raise BadInput(f"prefix {prefix!r} must be 1-32 letters, digits, '_' or '-'", field="prefix")
    if not 1 <= days <= 36500 or not 500 <= lease_ms <= 600_000:
        raise BadInput("days must be 1..36500 and the lease 500..600000 ms", field="days")
    rs = [parse_router(r) for r in routers]
    ids = [parse_identity(i) for i in identities]
    names = [r[0] for r in rs] + [i[0] for i in ids]
    dup = sorted({n for n in names if names.count(n) > 1} | ({"ca"} & set(names)))
    if dup:
        raise BadInput(f"identity names must be unique and not 'ca': {', '.join(dup)}", field="identity")
    reserved = sorted(n for n, role in ids if n in ROLES and n != role) + sorted(n for n, _, _ in rs if n in ROLES and
                                                                             n != "router")
    if reserved:
        raise BadInput(f"an identity may not be named after another role ({', '.join(reserved)}): the access control "
                       "matches certificates by name", field="identity")
    existing = [n for n in names if (out / n).exists()]
    if existing:
        raise BadInput(f"{out}: {', '.join(existing)} already exist; use a new folder (keys are never overwritten)",
                       field="out")
    if ca_from is not None:
        ca_dir = Path(ca_from)
        try:
            ca_key = serialization.load_pem_private_key((ca_dir / "ca.key").read_bytes(), None)
            ca_cert = x509.load_pem_x509_certificate((ca_dir / "ca.pem").read_bytes())
        except (OSError, ValueError) as e:
            raise BadInput(f"--ca {ca_dir}: cannot read ca.key and ca.pem ({e})", field="ca") from None
        issued = issued_names(ca_dir)
        again = [n for n in names if n in issued]
        if again:
            raise BadInput(f"this CA has already issued {', '.join(f'{n!r} (a {issued[n]})' for n in again)}: the "
                           "access control matches certificates by name, so a second certificate of that name would "
                           "have the first one's rights; choose another name", field="identity")
    else:
        if (out / "ca").exists():
            raise BadInput(f"{out / 'ca'} exists; to add identities to that cluster pass --ca {out / 'ca'}", field="ca")
        ca_key, ca_cert = make_ca(days)
        _write(out / "ca" / "ca.key", _pem(ca_key), private=True)
        _write(out / "ca" / "ca.pem", _pem(ca_cert))
        ca_dir, issued = out / "ca", {}
    mms = (max_message_size or DEFAULT_MAX_PAYLOAD + (1 << 20))
    endpoints = [_endpoint(a, p) for _, a, p in rs]
    members: dict[str, list[str]] = {r: [] for r in ROLES}
    for n, _, _ in rs:
        members["router"].append(cert_name(n, "router"))
    for n, role in ids:
        members[role].append(cert_name(n, role))
    section = acl(prefix, members)
    plan: list[tuple[str, str, list[str], list[str] | None]] = [(n, "router", [a], [_endpoint(a, p)]) for n, a, p in rs]
    plan += [(n, role, [], None) for n, role in ids]
    for name, role, hosts, listen in plan:
        folder = out / name
        key, cert = issue(ca_key, ca_cert, cert_name(name, role), hosts, days, role)
        _write(folder / "key.pem", _pem(key), private=True)
        _write(folder / "cert.pem", _pem(cert))
        _write(folder / "ca.pem", _pem(ca_cert))
        ident = Identity(name, role, prefix, endpoints, folder, listen)
        meta = {"name": name, "role": role, "prefix": prefix, "routers": endpoints}
        if listen:
            meta["listen"] = listen
        _write(folder / "identity.json", (json.dumps(meta, indent=2) + "\n").encode())
        cfg = zenoh_config(ident, mms, lease_ms, section if role == "router" else None)
        _write(folder / "zenoh.json5", (json.dumps(cfg, indent=2) + "\n").encode())
    issued.update({name: role for name, role, _, _ in plan})
    (ca_dir / ISSUED).write_text(json.dumps(issued, indent=1, sort_keys=True) + "\n")
    return {name: role for name, role, _, _ in plan}


ISSUED = "issued.json"  # beside ca.key: every name the CA has signed, and its role


def refresh_acl(ca_dir, router_folder) -> dict[str, list[str]]:
    """Write a router's access control again from every identity its CA has issued (``ca_dir``'s
    list): identities added with ``--ca`` after the router's configuration was written get their
    roles' rights once the router restarts. Returns ``{role: [common name, ...]}``."""
    ident = load_identity(router_folder)
    if ident.role != "router":
        raise BadInput(f"{router_folder} is the identity of a {ident.role}, not of a router", field="router")
    members: dict[str, list[str]] = {r: [] for r in ROLES}
    for name, role in sorted(issued_names(Path(ca_dir)).items()):
        if role in members:
            members[role].append(cert_name(name, role))
    path = ident.folder / "zenoh.json5"
    try:
        cfg = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise BadInput(f"{path}: cannot read the router's Zenoh config ({e})", field="router") from None
    cfg["access_control"] = acl(ident.prefix, members)
    _write(path, (json.dumps(cfg, indent=2) + "\n").encode())
    return {r: names for r, names in members.items() if names}


def issued_names(ca_dir: Path) -> dict[str, str]:
    """Every name the CA in ``ca_dir`` has issued a certificate to, and its role: its
    ``issued.json``, and for a CA made before that file the identities in the folder beside it."""
    out: dict[str, str] = {}
    registry = Path(ca_dir) / ISSUED
    if registry.exists():
        try:
            out.update(json.loads(registry.read_text()))
        except (OSError, ValueError) as e:
            raise BadInput(f"{registry}: cannot read the CA's list of issued names ({e})", field="ca") from None
    for d in Path(ca_dir).parent.iterdir():
        meta = d / "identity.json"
        if meta.is_file():
            try:
                out.setdefault(d.name, json.loads(meta.read_text())["role"])
            except (OSError, ValueError, KeyError):
                continue
    return out
