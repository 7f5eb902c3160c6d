"""CLI of a deployed cluster across hosts: ``deploy init | acl | show``.

See :mod:`shared.bus.deploy` for what the certificates and the access control allow, and
``deploy/README.md`` for running three hosts."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from shared.bus.deploy import IDENTITY_ROLES
from shared.cli.common import JSON_OPTION, app

deploy_app = typer.Typer(help="A cluster across several hosts, secured: a small CA, each process its own certificate, "
                              "Zenoh configs with TLS (mutual authentication) and access control per role.",
                         no_args_is_help=True)
app.add_typer(deploy_app, name="deploy")

IDENTITY_HELP = ("NAME:ROLE (or ROLE): one process's identity; roles: " + ", ".join(IDENTITY_ROLES) + ". Repeat; two "
                 "instances of a service get two names (pss-a:pss, pss-b:pss). Default: one of each role.")


@deploy_app.command("init")
def deploy_init(out: Path = typer.Argument(..., help="Folder for the CA and one sub-folder per identity (new)."),
                router: list[str] = typer.Option(..., "--router", help="A router: NAME=ADDRESS[:PORT] (it listens there, "
                                                 "TLS; default port 7447). Repeat for several routers."),
                identity: list[str] | None = typer.Option(None, "--identity", help=IDENTITY_HELP),
                prefix: str = typer.Option("mc", "--prefix", help="The cluster's key prefix."),
                days: int = typer.Option(825, "--days", help="Validity of the certificates, days."),
                lease_ms: int = typer.Option(3000, "--lease-ms", help="Link lease: a silent host counts as gone "
                                             "after this long (failover time)."),
                ca: Path | None = typer.Option(None, "--ca", help="Add identities to an existing cluster: its CA "
                                                 "folder (ca.pem, ca.key).")):
    """Make the CA, each identity's key and certificate, and its Zenoh config (TLS + access control).

    Run a process with MIRRORCOACH_DEPLOY=OUT/NAME. ca/ca.key signs certificates: keep it off the hosts."""
    from shared.bus.deploy import init

    made = init(out, router, identity or list(IDENTITY_ROLES), prefix=prefix, days=days, lease_ms=lease_ms, ca_from=ca)
    typer.echo(f"wrote {out}: " + ", ".join(f"{n} ({r})" for n, r in made.items()))
    typer.echo(f"run each process with MIRRORCOACH_DEPLOY={out}/<name>; keep {out}/ca/ca.key off the hosts")


@deploy_app.command("acl")
def deploy_acl(ca: Path = typer.Argument(..., help="The cluster's CA folder (its issued.json lists every identity)."),
               router: list[Path] = typer.Argument(..., help="Router identity folder(s) to write again.")):
    """Write routers' access control again from every identity the CA has issued.

    After `deploy init NEW --ca CA --identity alice:cli`, alice is in no role of a router written
    before her (the router logs her as refused); run this for each router and restart it."""
    from shared.bus.deploy import refresh_acl

    for folder in router:
        members = refresh_acl(ca, folder)
        typer.echo(f"wrote {folder / 'zenoh.json5'}: " + "; ".join(f"{r} {', '.join(n)}" for r, n in members.items()))
    typer.echo("restart the router(s) for the new access control to apply")


@deploy_app.command("show")
def deploy_show(folder: Path = typer.Argument(..., help="An identity's folder (OUT/NAME)."),
                as_json: bool = JSON_OPTION):
    """An identity: its role, routers, certificate's subject and expiry, what its role may do."""
    from cryptography import x509

    from shared.bus.deploy import load_identity

    ident = load_identity(folder)
    cert = x509.load_pem_x509_certificate((ident.folder / "cert.pem").read_bytes())
    info = {"name": ident.name, "role": ident.role, "prefix": ident.prefix, "routers": ident.routers,
            "subject": cert.subject.rfc4514_string(), "issuer": cert.issuer.rfc4514_string(),
            "expires": cert.not_valid_after_utc.isoformat()}
    if as_json:
        typer.echo(json.dumps(info))
    else:
        for k, v in info.items():
            typer.echo(f"{k:8} {', '.join(v) if isinstance(v, list) else v}")
