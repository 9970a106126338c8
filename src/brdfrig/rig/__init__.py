"""Device drivers behind small interfaces (camera, turntable) and their simulators."""
