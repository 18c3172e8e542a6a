"""A lossy link between a ground station and a vehicle, over loopback UDP:
each datagram, in each direction, is dropped, duplicated or delayed (which
reorders), by a seeded generator, within stated bounds.

    link = LossyLink(vehicle_port=14551, gcs=("127.0.0.1", 14550), spec="drop=0.1,seed=1")
    link.start()          # the vehicle sends to 127.0.0.1:14551, the ground station listens on 14550
    ...
    link.stop(); link.counts   # per direction: forwarded, dropped, duplicated, delayed

`spec` (comma-separated, each optional):
- `drop=P`: each datagram lost with probability P;
- `burst=S@EVERY`: every EVERY seconds (wall), S seconds in which every
  datagram is lost (a radio shadow);
- `dup=P`: each datagram forwarded twice with probability P;
- `delay=S`: each datagram held a uniform 0..S seconds (S at most 0.2),
  so that later ones may overtake it;
- `seed=N`: the generator's seed (default 1).

The vehicle's side is learnt from its first datagram (its source address),
as a ground station learns it.
"""
import heapq
import random
import select
import socket
import threading
import time

MAX_DELAY_S = 0.2


def parse(spec):
    """`spec`'s settings as a dict (see the module's documentation)."""
    out = {"drop": 0.0, "burst": None, "dup": 0.0, "delay": 0.0, "seed": 1}
    for part in filter(None, (spec or "").split(",")):
        key, _, value = part.partition("=")
        if key == "burst":
            s, _, every = value.partition("@")
            out["burst"] = (float(s), float(every))
        elif key in ("drop", "dup", "delay"):
            out[key] = float(value)
        elif key == "seed":
            out["seed"] = int(value)
        else:
            raise ValueError(f"lossy link: unknown setting {key!r} in {spec!r}")
    if not (0.0 <= out["drop"] < 1.0 and 0.0 <= out["dup"] <= 1.0 and 0.0 <= out["delay"] <= MAX_DELAY_S):
        raise ValueError(f"lossy link: out of range in {spec!r} (drop < 1, dup <= 1, delay <= {MAX_DELAY_S} s)")
    if out["burst"] and not (0.0 < out["burst"][0] < out["burst"][1]):
        raise ValueError(f"lossy link: a burst shorter than its period, in {spec!r}")
    return out


class LossyLink:
    def __init__(self, vehicle_port, gcs, spec):
        self.cfg = parse(spec)
        self.rng = random.Random(self.cfg["seed"])
        self.gcs = gcs
        self.vehicle_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle_side.bind(("127.0.0.1", vehicle_port))
        self.gcs_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gcs_side.bind(("127.0.0.1", 0))
        self.vehicle = None
        self.queue = []  # (due wall s, order, socket, data, address)
        self.order = 0
        self.counts = {d: {"forwarded": 0, "dropped": 0, "duplicated": 0, "delayed": 0}
                       for d in ("to_gcs", "to_vehicle")}
        self.t0 = None
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self):
        self.t0 = time.time()
        self._thread.start()

    def stop(self):
        self._stop = True
        self._thread.join(timeout=2)

    def in_burst(self, now):
        b = self.cfg["burst"]
        return b is not None and (now - self.t0) % b[1] < b[0]

    def _take(self, data, out, to, direction, now):
        c = self.counts[direction]
        if self.in_burst(now) or self.rng.random() < self.cfg["drop"]:
            c["dropped"] += 1
            return
        copies = 2 if self.rng.random() < self.cfg["dup"] else 1
        c["duplicated"] += copies - 1
        for _ in range(copies):
            delay = self.rng.uniform(0.0, self.cfg["delay"]) if self.cfg["delay"] > 0 else 0.0
            c["delayed"] += delay > 0
            self.order += 1
            heapq.heappush(self.queue, (now + delay, self.order, out, data, to))

    def _run(self):
        socks = [self.vehicle_side, self.gcs_side]
        while not self._stop:
            wait = 0.05 if not self.queue else max(0.0, min(0.05, self.queue[0][0] - time.time()))
            ready, _, _ = select.select(socks, [], [], wait)
            now = time.time()
            for s in ready:
                try:
                    data, addr = s.recvfrom(65535)
                except OSError:
                    continue
                if s is self.vehicle_side:
                    self.vehicle = addr
                    self._take(data, self.gcs_side, self.gcs, "to_gcs", now)
                elif self.vehicle is not None:
                    self._take(data, self.vehicle_side, self.vehicle, "to_vehicle", now)
            while self.queue and self.queue[0][0] <= time.time():
                _, _, out, data, to = heapq.heappop(self.queue)
                try:
                    out.sendto(data, to)
                    self.counts["to_gcs" if out is self.gcs_side else "to_vehicle"]["forwarded"] += 1
                except OSError:
                    pass
