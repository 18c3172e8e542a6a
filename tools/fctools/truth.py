"""A simulator's true state, from its stream of JSON datagrams over UDP.

Two streams carry it:
- tools/rotorpy_hil.py's (`--truth-port`): `t`, simulated s; `ned`, north,
  east, down about the start, m;
- `sil-host crtp --truth-to` (sil-host/src/crtp.rs): `t`, plant s; `x`,
  `y`, `z`, the Crazyflie's world frame (z up), m; the attitude quaternion;
  `armed` and `flying`; `id`, the vehicle (0 to N-1) of a swarm
  (`--count N`), 0 when absent.

`pos` is the position as the stream gives it, in the stream's frame. `last`,
`track` and what reads them are vehicle 0's; `lasts` and `tracks` hold
every vehicle's, by id.
"""
import asyncio
import json
import math
import select
import socket
import threading
import time


class Truth:
    """The latest datagram of a truth stream on 127.0.0.1:`port`, and the
    track of positions so far.

    Read it by calling `poll()` (it drains what has arrived), or `follow()`
    once: a thread then reads it as it arrives, for scripts that block in
    a client library's calls.
    """

    def __init__(self, port):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.last = None
        self.track = []
        self.lasts = {}  # id -> the latest datagram
        self.tracks = {}  # id -> [(t, position)]
        self.walls = []  # (simulated s, wall s) of each sleep()
        self._thread = None
        self._stop = False

    @property
    def t(self):
        """The stream's time of the latest datagram, s (None before one)."""
        return self.last["t"] if self.last else None

    @property
    def pos(self):
        """The latest position, m, in the stream's frame (None before one)."""
        return None if self.last is None else position_of(self.last)

    def poll(self):
        """Takes every datagram that has arrived."""
        while True:
            try:
                data, _ = self.sock.recvfrom(1024)
            except BlockingIOError:
                return
            m = json.loads(data)
            i = m.get("id", 0)
            self.lasts[i] = m
            self.tracks.setdefault(i, []).append((m["t"], position_of(m)))
            if i == 0:
                self.last = m
                self.track.append(self.pos)

    def reset(self):
        """Forgets the latest datagram (a new session's clock starts anew)
        and every vehicle's track."""
        self.last = None
        self.lasts = {}
        self.tracks = {}

    def follow(self):
        """Reads the stream in a thread of its own from now on."""

        def run():
            while not self._stop:
                select.select([self.sock], [], [], 0.5)
                self.poll()

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def close(self):
        """Stops the reading thread (if any)."""
        self._stop = True
        if self._thread:
            self._thread.join(timeout=2)

    def sleep(self, secs, every=None):
        """Waits `secs` of the stream's time, calling `every()` each 20 ms of
        it meanwhile (a set-point stream at 50 Hz); at most 50 × `secs` of
        wall time. In the SIL the plant keeps wall time; in QEMU it runs
        slower (the emulated image), and a flight's phases are timed on the
        vehicle's clock, as cflib's durations are."""
        t0, w0 = self._now(), time.time()
        called = None
        while self._now() < t0 + secs and time.time() < w0 + 50 * secs:
            if every and (called is None or self._now() >= called + 0.02):
                called = self._now()
                every()
            time.sleep(0.002)
        self.walls.append((self._now() - t0, time.time() - w0))

    def _now(self):
        """The stream's time, s (0 before a datagram), read first unless
        the thread reads it."""
        if not self._thread:
            self.poll()
        return self.t or 0.0

    async def slowdown(self, span_s=0.5):
        """Wall seconds per simulated second, over the next `span_s`
        simulated (what queued before is read first: it arrived earlier)."""
        self.poll()
        while self.t is None:
            await asyncio.sleep(0.05)
            self.poll()
        wall0, t0 = time.time(), self.t
        while self.t - t0 < span_s:
            await asyncio.sleep(0.02)
            self.poll()
        return (time.time() - wall0) / (self.t - t0)

    def closest(self, pos, since):
        """The closest the track came to `pos` after entry `since`, m."""
        self.poll()
        return min((math.dist(p, pos) for p in self.track[since:]), default=math.inf)

    def dist(self, pos):
        """The latest position's distance from `pos`, m (inf before one)."""
        self.poll()
        return math.inf if self.pos is None else math.dist(self.pos, pos)

    def closest_of(self, i, pos, since_t):
        """The closest vehicle `i`'s track came to `pos` from stream time
        `since_t` on, m."""
        self.poll()
        return min((math.dist(p, pos) for t, p in list(self.tracks.get(i, [])) if t >= since_t), default=math.inf)

    def min_separation(self):
        """The least distance between two vehicles' positions at the same
        stream time, m, and when (inf, None with fewer than two)."""
        self.poll()
        at = {}
        for i, track in list(self.tracks.items()):
            for t, p in track:
                at.setdefault(round(t, 3), {})[i] = p
        best = (math.inf, None)
        for t, ps in at.items():
            ps = list(ps.values())
            for a in range(len(ps)):
                for b in range(a + 1, len(ps)):
                    best = min(best, (math.dist(ps[a], ps[b]), t), key=lambda x: x[0])
        return best


def position_of(m):
    """A datagram's position, in the stream's frame."""
    return m["ned"] if "ned" in m else (m["x"], m["y"], m["z"])
