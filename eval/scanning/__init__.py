"""The scan-houses command: scanned houses built on the backend, and their scan-likeness report."""
