"""The bus: Zenoh configuration, the service runtime and the client helper (no math here)."""
