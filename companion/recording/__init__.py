"""The flight record: MCAP files written in a process of their own, with the flight in
Foxglove's schemas beside the service's own channels (docs/groundstation.md)."""
