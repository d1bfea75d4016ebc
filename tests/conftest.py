import axialmix  # noqa: F401  (float64 for every test)
