"""The service's Zenoh side: inputs (byte caps, rate limits, hand-over to the decode
workers), the decoder, the outbox thread, who sent what (actors, access-control
denials) and the exposure checks and fleet credentials (docs/security.md)."""
