"""Planning a sweep: its runs, each with its content-hash id, and the time they will take."""
