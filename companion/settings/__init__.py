"""The configuration: the file's schema and checks, the safety envelope it sets, and
the run-time changes allowed inside it (docs/service.md, "Run-time configuration")."""
