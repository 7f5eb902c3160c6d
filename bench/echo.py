"""``python -m bench.echo``: a service with one verb (echo a blob), built from the same runtime
as every mirrorcoach service, to measure what the bus and the runtime add to a request."""

from __future__ import annotations

from schemas.base import Array, Endpoint, F, Map, Message

ECHO = {"echo": Endpoint("echo", Message("bench.echo", Map({"blob": F(Array(shape=(None,)))})),
                         Message("bench.echo.reply", Map({"blob": F(Array(shape=(None,)))})), "return the blob")}


def main() -> int:
    from shared.bus.runtime import Service

    svc = Service("echo", ECHO)
    svc.handler("echo")(lambda req: {"blob": req["blob"]})
    return svc.run()


if __name__ == "__main__":
    raise SystemExit(main())
