"""Child processes of the tools' flights: a flight controller (`sil-host`)
that ends before the flight does is a failure said at once, never a wait.

rotorpy's `PX4Multirotor` waits on its TCP port (`tcpin`) for as long as it
takes for a flight controller to connect, and a socket read waits for a
datagram that will never come: without this, a `sil-host` that exits early
(say, with no firmware image to run) leaves the tool, and CI, waiting.
"""
import os
import sys
import threading


class EndsWithFlight:
    """Watches `proc` from a thread: should it exit before `done()` is called,
    the tool stops `others` (the tool's other children: a ground station, a
    radio bridge), prints what ended and exits at once with status 2 (the
    child's own stderr, inherited or drained, has already said why)."""

    def __init__(self, proc, what, others=()):
        self.proc, self.what, self.others = proc, what, list(others)
        self._done = threading.Event()
        threading.Thread(target=self._watch, daemon=True).start()

    def done(self):
        """The flight is over: the child may end now."""
        self._done.set()

    def _watch(self):
        rc = self.proc.wait()
        if not self._done.is_set():
            for p in self.others:
                if p is not None and p.poll() is None:
                    p.kill()
            sys.stderr.write(f"FAIL: {self.what} exited ({rc}) before the flight ended\n")
            sys.stderr.flush()
            os._exit(2)
