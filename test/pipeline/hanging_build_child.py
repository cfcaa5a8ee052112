"""A build child that takes a request and never answers (test_build_process: close() during a
build). Run as ``python -m hanging_build_child`` with this directory on PYTHONPATH."""

import sys
import time

if __name__ == "__main__":
    sys.stdin.buffer.read(1)      # a request began
    sys.stdout.buffer.write(b"")  # nothing: the build never ends
    while True:
        time.sleep(60)
