"""The Crazyradio link a Crazyflie meets, as a model: Enhanced ShockBurst
(ESB) between the radio dongle (the PTX, driven by cflib's radio driver)
and the Crazyflie's nRF51 (the PRX), with the air between them losing
packets.

What each side does is what its own code does:

- `Prx` is the nRF51's receiver (crazyflie2-nrf-firmware's `esb.c`): a
  packet whose PID and CRC are the previous one's is a retransmission, and
  is answered with the same acknowledgement again, not delivered; a
  downlink packet waits in a queue of 16 and rides on the acknowledgement of
  the next uplink; with "safelink" on, one bit of the CRTP header counts the
  uplink (a packet whose bit is the last one's is a duplicate, not
  delivered) and one the downlink (the dongle's bit says whether it has the
  last one; if not, it is sent again).
- `Ptx` is the Crazyradio and cflib's `radiodriver.py` over it: each packet
  is sent up to 1 + ARC times (cflib sets ARC 3) with one PID; a packet not
  acknowledged is sent again by the driver, with a new PID, and after 100
  in a row the driver gives up: cflib's "Too many packets lost", a link
  error. cflib asks for safelink at the start (ten tries); with it, the
  driver counts the bits.
- `Air` loses each packet on the air, uplink and acknowledgement alike,
  with a probability, and every packet in a burst (a radio shadow), by a
  seeded generator.

So a lost acknowledgement makes a duplicate (the same packet sent again),
which the nRF51 drops (by PID within the dongle's retries; by the safelink
bit across the driver's), and nothing is lost or doubled unless the driver
gives up. The CRC is stood in for by the bytes themselves: two different
packets with one PID never pass for a retry here, where a real 16-bit CRC
could collide once in 65 536.

`self_test()` runs both sides against each other on a lossy air and
checks exactly that (and that without safelink the duplicates pass and
downlink packets go missing).
"""
import collections
import random

from fctools.lossy import parse as parse_lossy

ARC = 3                      # the dongle's automatic retries (cflib's _nr_of_arc_retries)
DRIVER_RETRIES = 100         # cflib's _nr_of_retries: sends in a row not acknowledged
TXQ_LEN = 16                 # the nRF51's downlink queue (esb.c's TXQ_LEN, one slot kept free)
SAFELINK = bytes((0xFF, 0x05, 0x01))
# Wall time one send takes (a USB round trip of the dongle), and one that is
# not acknowledged (1 + ARC attempts, each waiting the ARD cflib sets for a
# 32-byte acknowledgement, 0.5 ms at 2 Mbit/s), s.
SEND_S = 0.001
FAILED_SEND_S = SEND_S + (1 + ARC) * 0.0005


def parse(spec):
    """A radio's settings from `drop=P,burst=S@EVERY,seed=N,safelink=0|1`
    (the lossy link's loss settings; duplicates and reordering are what
    the radio's retries make, not settings)."""
    parts = [p for p in (spec or "").split(",") if p]
    safelink = True
    rest = []
    for p in parts:
        key, _, value = p.partition("=")
        if key == "safelink":
            if value not in ("0", "1"):
                raise ValueError(f"radio: safelink={value!r}: 0 or 1")
            safelink = value == "1"
        elif key in ("dup", "delay"):
            raise ValueError(f"radio: {key} is not a setting of the radio (its retries make the duplicates)")
        else:
            rest.append(p)
    cfg = parse_lossy(",".join(rest))
    return {"drop": cfg["drop"], "burst": cfg["burst"], "seed": cfg["seed"], "safelink": safelink}


class Air:
    """Loses packets: each with probability `drop`, all of them while in a
    burst (`burst=(S, EVERY)`: the last S s of every EVERY s on the clock
    passed to `lost`, so that the link starts outside one)."""

    def __init__(self, drop, burst=None, seed=1):
        self.drop = drop
        self.burst = burst
        self.rng = random.Random(seed)
        self.sent = 0
        self.lost_count = 0

    def lost(self, now=0.0):
        self.sent += 1
        shadow = self.burst is not None and now % self.burst[1] >= self.burst[1] - self.burst[0]
        gone = shadow or self.rng.random() < self.drop
        self.lost_count += gone
        return gone


class Prx:
    """The nRF51's ESB receiver (see the module's documentation)."""

    def __init__(self):
        self.prev = None            # (PID, bytes) of the last packet received
        self.curr_up = 1
        self.curr_down = 1
        self.safelink = False
        self.txq = collections.deque()
        self.service = None         # the answer to a safelink request
        self.last = ("ack", b"")    # what the last acknowledgement carried
        self.counts = {"retransmits": 0, "duplicates": 0, "resent_down": 0, "queue_full": 0}

    def queue(self, packet):
        """A downlink packet from the STM32; False when the queue is full (dropped)."""
        if len(self.txq) >= TXQ_LEN - 1:
            self.counts["queue_full"] += 1
            return False
        self.txq.append(bytearray(packet))
        return True

    def _ack(self, retry):
        if retry:
            self.counts["resent_down"] += self.last[0] == "queue"
            return self.last[1]
        if self.last[0] == "queue" and self.txq:
            self.txq.popleft()       # the previous one arrived: the dongle moved on
        if self.last[0] == "service":
            self.service = None
        if self.service is not None:
            self.last = ("service", self.service)
        elif self.txq:
            if self.safelink:
                self.txq[0][0] = (self.txq[0][0] & 0xF3) | self.curr_down << 2
            self.last = ("queue", bytes(self.txq[0]))
        else:
            self.last = ("ack", bytes((0xF3 | self.curr_down << 2,)))
        return self.last[1]

    def receive(self, pid, data):
        """One packet heard: (the acknowledgement's payload, the packet to
        hand the STM32 or None)."""
        data = bytes(data)
        if self.prev == (pid, data):
            self.counts["retransmits"] += 1
            return self._ack(True), None
        self.prev = (pid, data)
        if len(data) == 3 and data[0] & 0xF3 == 0xF3 and data[1] == 0x05:
            self.safelink = bool(data[2])
            self.service = data
            ack = self._ack(False)
            self.curr_up = self.curr_down = 1
            return ack, None
        up = None
        if not self.safelink or (data[0] & 0x08) != self.curr_up << 3:
            up = data
            self.curr_up ^= 1
        else:
            self.counts["duplicates"] += 1
        if not self.safelink or (data[0] & 0x04) != self.curr_down << 2:
            self.curr_down ^= 1
            return self._ack(False), up
        return self._ack(True), up


class Ptx:
    """The Crazyradio and cflib's radio driver (see the module's documentation)."""

    def __init__(self, prx, air, safelink=True):
        self.prx = prx
        self.air = air
        self.want_safelink = safelink
        self.safelink = False
        self.pid = 0
        self.curr_up = 0
        self.curr_down = 1
        self.fails = 0              # sends in a row not acknowledged
        self.delivered = []         # what the PRX handed the STM32 during the last send
        self.counts = {"sends": 0, "attempts": 0, "not_acked": 0, "link_errors": 0}

    def _send(self, data, now):
        """One send of the dongle: the acknowledgement's payload, or None."""
        self.counts["sends"] += 1
        self.pid = (self.pid + 1) % 4
        for _ in range(1 + ARC):
            self.counts["attempts"] += 1
            if self.air.lost(now):
                continue
            ack, up = self.prx.receive(self.pid, data)
            if up is not None:
                self.delivered.append(up)
            if self.air.lost(now):
                continue
            return ack
        self.counts["not_acked"] += 1
        return None

    def start(self, now=0.0):
        """cflib's driver asks for safelink, up to ten times."""
        for _ in range(10 if self.want_safelink else 0):
            if self._send(SAFELINK, now) == SAFELINK:
                self.safelink = True
                self.curr_up = self.curr_down = 0
                break
        self.delivered.clear()

    def send(self, data, now=0.0):
        """One send of cflib's driver: (acknowledged, the downlink packet it
        brought, or None). Not acknowledged, the caller sends `data` again;
        after DRIVER_RETRIES in a row it is a link error (counted) and the
        count starts again."""
        data = bytearray(data)
        if self.safelink:
            data[0] = (data[0] & 0xF3) | self.curr_up << 3 | self.curr_down << 2
        ack = self._send(data, now)
        if ack is None:
            self.fails += 1
            if self.fails >= DRIVER_RETRIES:
                self.counts["link_errors"] += 1
                self.fails = 0
            return False, None
        self.fails = 0
        new = True
        if self.safelink:
            new = len(ack) > 0 and (ack[0] & 0x04) == self.curr_down << 2
            if new:
                self.curr_down ^= 1
            self.curr_up ^= 1
        # The nRF51's empty acknowledgement (0xF3 and its bit, alone) is no packet.
        if not new or (len(ack) == 1 and ack[0] & 0xF3 == 0xF3):
            return True, None
        return True, bytes(ack)


def self_test(n=20_000, drop=0.3, seed=1):
    """Both sides on a lossy air, an STM32 that answers every uplink packet
    with one numbered downlink: what arrived, each way, against what was
    sent. Returns a list of (ok, what) and the figures (a dict)."""
    out, figures = [], {}
    for safelink in (True, False):
        air = Air(drop, seed=seed)
        prx = Prx()
        ptx = Ptx(prx, air, safelink=safelink)
        ptx.start()
        sent_up, got_up, sent_down, got_down = [], [], [], []
        i = 0
        while len(sent_up) < n:
            body = bytes((0x20,)) + i.to_bytes(4, "little")
            sent_up.append(body[1:])
            while True:
                ok, down = ptx.send(body)
                for p in ptx.delivered:
                    got_up.append(p[1:])
                    reply = bytes((0x30,)) + (len(sent_down)).to_bytes(4, "little")
                    if prx.queue(reply):
                        sent_down.append(reply[1:])
                ptx.delivered.clear()
                if down is not None:
                    got_down.append(down[1:])
                if ok:
                    break
            i += 1
        # Drain the downlink queue with null packets.
        for _ in range(10 * TXQ_LEN):
            ok, down = ptx.send(b"\xff")
            ptx.delivered.clear()
            if down is not None:
                got_down.append(down[1:])
        dups = prx.counts["retransmits"] + prx.counts["duplicates"]
        if safelink:
            figures.update(on_air=air.sent, lost_on_air=air.lost_count, duplicates_dropped=dups,
                           link_errors=ptx.counts["link_errors"])
            out.append((ptx.safelink and got_up == sent_up and got_down == sent_down and dups > 0
                        and ptx.counts["link_errors"] == 0,
                        (f"safelink, {100 * drop:.0f} % lost on the air: {n} uplink and {len(sent_down)} downlink "
                        f"packets arrived exactly once, in order ({air.lost_count} of {air.sent} lost on the air, "
                        f"{dups} duplicates a retry made dropped by the nRF51, {ptx.counts['link_errors']} link "
                        f"errors)")))
        else:
            figures.update(unsafe_doubled=len(got_up) - len(set(got_up)),
                           unsafe_lost_down=len(sent_down) - len(got_down))
            out.append((len(got_up) > len(set(got_up)) and len(got_down) < len(sent_down),
                        (f"without safelink the same air doubles {len(got_up) - len(set(got_up))} uplink packets "
                        f"and loses {len(sent_down) - len(got_down)} downlink packets (what safelink is for)")))
    return out, figures
