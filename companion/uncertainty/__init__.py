"""Where the velocity-to-sigma model comes from: the configured one, or the in-flight
estimator (filterpy) and its link to the service (docs/estimator.md)."""
