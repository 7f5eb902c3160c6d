"""The bus: the msgpack codec, Zenoh configuration, the client, the service runtime, the router,
clip files packed for the bus, deployment identities, and the local cluster's supervisor
(``cluster``, ``pidfiles``). One layer with ``schemas/`` (the runtime checks the contracts; the
contracts use the bus's limits). No math here: imports ``motion``, ``io`` and the base modules."""
