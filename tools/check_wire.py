#!/usr/bin/env python3
"""A flight-controller client written from the book's wire-format section (docs/book/src/protocols/wire.md)
only (COBS + CRC-32C + postcard, protocol v3), run against `sil-host serve`:
it sends garbage first, then handshakes, selects the LQR, holds a set-point
and flies a few hundred lockstep steps of a crude vertical model, and checks
every answer. Usage: check_wire.py path/to/sil-host. Prints
`wire check: N passed, M failed`."""
import socket
import struct
import subprocess
import sys
import time

from fctools.checks import Checks

check = Checks("wire", quiet=True)


def crc32c(data):
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def cobs_encode(data):
    out, block = bytearray(), bytearray()
    for b in data:
        if b == 0:
            out += bytes([len(block) + 1]) + block
            block = bytearray()
        else:
            block.append(b)
            if len(block) == 254:
                out += bytes([255]) + block
                block = bytearray()
    out += bytes([len(block) + 1]) + block
    return bytes(out)


def cobs_decode(data):
    out, i = bytearray(), 0
    while i < len(data):
        code = data[i]
        out += data[i + 1:i + code]
        i += code
        if code < 255 and i < len(data):
            out.append(0)
    return bytes(out)


def varint(n):
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def frame(payload):
    return cobs_encode(payload + struct.pack("<I", crc32c(payload))) + b"\x00"


def f32s(*v):
    return b"".join(struct.pack("<f", x) for x in v)


def sp(pos, yaw):
    return f32s(*pos, 0, 0, 0, 0, 0, 0, 0, 0, 0, yaw, 0)


class Reader:
    def __init__(self, data):
        self.d, self.i = data, 0

    def varint(self):
        n = s = 0
        while True:
            b = self.d[self.i]
            self.i += 1
            n |= (b & 0x7F) << s
            s += 7
            if not b & 0x80:
                return n

    def f32(self):
        v = struct.unpack_from("<f", self.d, self.i)[0]
        self.i += 4
        return v

    def byte(self):
        self.i += 1
        return self.d[self.i - 1]


def parse(payload):
    r = Reader(payload)
    tag = r.varint()
    if tag == 0:
        return ("HelloAck", r.varint(), r.byte())
    if tag == 1:
        return ("Actuator", r.varint(), [r.f32() for _ in range(4)], r.byte())
    if tag == 2:
        seq, cycles, iters = r.varint(), r.varint(), r.varint()
        counters = [r.varint() for _ in range(9)]
        return ("Telemetry", seq, cycles, iters, counters, r.byte())
    if tag == 3:
        return ("Heartbeat", r.varint())
    if tag == 6:
        index, count = r.varint(), r.varint()
        name = bytes(r.byte() for _ in range(16)).rstrip(b"\x00").decode()
        return ("Param", index, count, name, r.f32(), r.byte())
    return ("?", tag)


class Client:
    def __init__(self, addr):
        self.s = socket.create_connection(addr, timeout=5)
        self.buf = b""
        self.frames = self.bad_crc = 0

    def send(self, payload):
        self.s.sendall(frame(payload))

    def recv(self):
        while b"\x00" not in self.buf:
            chunk = self.s.recv(4096)
            if not chunk:
                raise EOFError("closed")
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\x00", 1)
        data = cobs_decode(raw)
        payload, crc = data[:-4], struct.unpack("<I", data[-4:])[0]
        self.frames += 1
        self.bad_crc += crc != crc32c(payload)
        return parse(payload)


def main():
    exe = sys.argv[1]
    port = 17000 + (int(time.time()) % 2000)
    srv = subprocess.Popen([exe, "serve", "--listen", f"127.0.0.1:{port}", "--max-clients", "2"],
                           stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.05)
        # That probe was client 1 (it hung up). Client 2: garbage, then a flight.
        c = Client(("127.0.0.1", port))
        c.s.sendall(bytes(range(1, 200)) + b"\x00\x00" + b"\x05\x01\x02\x00" + b"\xff" * 300 + b"\x00")
        c.send(varint(0) + varint(6))  # Hello v6
        ack = c.recv()
        check(ack == ("HelloAck", 6, 1), f"handshake accepted: {ack}")
        c.send(varint(9) + varint(0))  # ParamRead 0
        p = c.recv()
        check(p[:4] == ("Param", 0, p[2], "VEH_MASS") and abs(p[4] - 0.65) < 1e-6 and p[5] == 0 and p[2] > 16,
              f"parameter 0 is the OS4's mass: {p}")
        c.send(varint(8) + varint(0) + f32s(-1.0))  # ParamSet VEH_MASS = -1
        p = c.recv()
        check(p[0] == "Param" and abs(p[4] - 0.65) < 1e-6 and p[5] == 2,
              f"a negative mass is refused (out of range), the old value kept: {p}")
        c.send(varint(1) + varint(3) + b"\x01")  # Select LqrQuat, feed-forward
        c.send(varint(2) + sp((0.0, 0.0, -2.0), 0.0))  # Setpoint: hover at 2 m
        # A crude vertical model: the vehicle starts at 1 m, thrust U1 lifts it.
        m, g, z, vz, dt = 0.65, 9.81, -1.0, 0.0, 0.002
        last_counters = None
        for k in range(1, 1501):
            state = f32s(0, 0, z, 0, 0, vz, 1, 0, 0, 0, 0, 0, 0)
            c.send(varint(4) + varint(k) + varint(k * 2000) + state)
            a, t = c.recv(), c.recv()
            if a[0] != "Actuator" or a[1] != k or t[0] != "Telemetry" or t[1] != k:
                check(False, f"lockstep answer for step {k}: {a} {t}")
                break
            u1 = a[2][0]
            vz += (g - u1 / m) * dt
            z += vz * dt
            last_counters = t[4]
        check(abs(z + 2.0) < 0.05, f"climbed to the set-point altitude: z = {z:.3f} m")
        check(0 <= a[2][0] <= 45.1, "U1 inside the box")
        check(last_counters is not None and last_counters[0] >= 1500, f"frames counted ok: {last_counters}")
        check(last_counters is not None and sum(last_counters[1:5]) >= 1, f"garbage counted: {last_counters}")
        check(last_counters is not None and last_counters[8] == 0, "no failsafe entries")
        c.send(varint(5) + varint(77))
        check(c.recv() == ("Heartbeat", 77), "heartbeat echoed")
        check(c.bad_crc == 0 and c.frames > 3000, f"{c.frames} answers, {c.bad_crc} with a bad CRC")
        c.s.close()
    except Exception as e:  # noqa: BLE001 -- a protocol error is a failed check, not a crash
        check(False, f"client error: {e!r}")
    finally:
        srv.kill()
        srv.wait()
    print(check.summary())
    sys.exit(check.exit_code())


main()
