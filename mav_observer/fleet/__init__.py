"""Several vehicles, one target: rays shared over Zenoh and their fusion (docs/fleet.md)."""
