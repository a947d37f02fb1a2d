"""Training the confidence network: the training loop (``trainer``), recipes of shipped weights (``recipe``) and
the cached engine runs that make training maps (``runs``)."""
