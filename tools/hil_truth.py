"""rotorpy's truth as tools/rotorpy_hil.py streams it to a ground-station
script (UDP datagrams of JSON: `t`, simulated s; `ned`, north, east, down
about the start, m), for the scripts' checks (tools/mavsdk_flight.py,
tools/mavproxy_session.py)."""
import asyncio
import json
import math
import socket
import time


class Truth:
    """rotorpy's position (NED about the start, m) and time (s), latest."""

    def __init__(self, port):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.t, self.ned = None, None
        self.track = []

    def poll(self):
        while True:
            try:
                data, _ = self.sock.recvfrom(256)
            except BlockingIOError:
                return
            m = json.loads(data)
            self.t, self.ned = m["t"], m["ned"]
            self.track.append(self.ned)

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

    def closest(self, ned, since):
        """The closest rotorpy came to `ned` after track entry `since`, m."""
        self.poll()
        return min((math.dist(p, ned) for p in self.track[since:]), default=math.inf)

    def dist(self, ned):
        self.poll()
        if self.ned is None:
            return math.inf
        return math.dist(self.ned, ned)
