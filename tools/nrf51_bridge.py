#!/usr/bin/env python3
"""Plays a Crazyflie 2.1's nRF51 radio chip for the `firmware-crtp` image in QEMU.

cflib's `udp://` driver on one side (one datagram = one CRTP packet, answers to
the address of the last datagram), the image's USART6 on the other, in syslink
(`0xBC 0xCF type len data ckA ckB`, Fletcher-8 over type, length and data), as
the nRF51 firmware (bitcraze/crazyflie2-nrf-firmware) speaks it:

- every CRTP packet from the client goes up as RADIO_RAW;
- when the client is quiet the bridge polls with null packets (0xFF), since
  the STM32 answers each uplink packet with at most one downlink packet; as
  cflib's radio driver does, every millisecond while packets come back and
  every 10 ms after 10 polls in a row brought nothing (a poll counts as empty
  when no downlink arrived before the next one). This also keeps the bridge
  from burying an image that runs slower than real time (QEMU) in polls that
  would delay the client's packets behind them;
- the STM32's RADIO_READY at boot is echoed (the radio is on);
- a battery report (PM_BATTERY_STATE: flags, V, A) every 100 ms.

With `--radio SPEC` (e.g. `drop=0.3,burst=0.1@5,seed=1`) the radio between
them is modelled, and loses packets (`tools/fctools/radio.py`): the bridge
plays the Crazyradio and cflib's radio driver on one side (ARC retries, the
driver's resends, safelink's bits, "Too many packets lost" after 100 sends
in a row not acknowledged) and the nRF51's ESB receiver on the other
(retransmissions answered again and not delivered, the downlink queued and
carried on the next acknowledgement); one send at most every millisecond,
as the dongle's USB round trip allows. cflib's `udp://` driver, which never
resends, sees what cflib sees over a Crazyradio. `safelink=0` plays an nRF51
without safelink (duplicates pass, downlink packets can be lost).

Usage: nrf51_bridge.py [--syslink 127.0.0.1:19880] [--listen 127.0.0.1:19850]
                       [--vbat 3.9] [--wait 30] [--radio SPEC] [--self-test]
Stops when the image closes USART6 (QEMU stopped) or on Ctrl-C; prints what it
relayed as one JSON line.
"""
import argparse
import collections
import json
import select
import socket
import struct
import sys
import time

from fctools import radio

START = b'\xbc\xcf'
MTU = 64
RADIO_RAW = 0x00
RADIO_READY = 0x0B
PM_BATTERY_STATE = 0x13
NULL_PACKET = b'\xff'
POLL_S = 0.001
IDLE_POLL_S = 0.01
EMPTY_POLLS = 10
BATTERY_S = 0.1


def checksum(body):
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def frame(ty, data=b''):
    if len(data) > MTU:
        raise ValueError(f'syslink payload of {len(data)} bytes: at most {MTU}')
    body = bytes((ty, len(data))) + data
    return START + body + checksum(body)


class Decoder:
    """The syslink receive state machine (bad length or checksum: resynchronise)."""

    def __init__(self):
        self.buf = bytearray()
        self.bad = 0

    def feed(self, data):
        self.buf += data
        out = []
        while True:
            i = self.buf.find(START)
            if i < 0:
                del self.buf[:max(0, len(self.buf) - 1)]
                return out
            del self.buf[:i]
            if len(self.buf) < 4:
                return out
            n = self.buf[3]
            if n > MTU:
                self.bad += 1
                del self.buf[:2]
                continue
            if len(self.buf) < n + 6:
                return out
            body = bytes(self.buf[2:4 + n])
            if checksum(body) == bytes(self.buf[4 + n:6 + n]):
                out.append((body[0], body[2:]))
                del self.buf[:n + 6]
            else:
                self.bad += 1
                del self.buf[:2]


def connect(addr, wait_s):
    host, port = addr.rsplit(':', 1)
    deadline = time.time() + wait_s
    while True:
        try:
            s = socket.create_connection((host, int(port)), timeout=1)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.setblocking(False)
            return s
        except OSError:
            if time.time() > deadline:
                sys.exit(f'nrf51_bridge: nothing listens on {addr} (start `sil-host crtp --target qemu` first)')
            time.sleep(0.1)


def from_client(udp):
    """The client's datagrams waiting on `udp` (one CRTP packet each, 1 to 31
    bytes; others are not packets), each with its sender."""
    got = []
    while True:
        try:
            data, client = udp.recvfrom(64)
        except BlockingIOError:
            return got
        if 1 <= len(data) <= 31:
            got.append((data, client))


def from_image(link, dec, out, stats):
    """The image's bytes waiting on `link`, decoded: the downlink packets
    (RADIO_RAW), counted; RADIO_READY echoed into `out`. None once the image
    has closed USART6."""
    try:
        data = link.recv(4096)
    except BlockingIOError:
        data = None
    if data == b'':
        return None
    down = []
    for ty, payload in dec.feed(data or b''):
        if ty == RADIO_RAW:
            stats['downlink'] += 1
            down.append(payload)
        elif ty == RADIO_READY:
            stats['ready'] += 1
            out += frame(RADIO_READY)
        else:
            stats['other'] += 1
    return down


def to_image(link, out, stats, now, last_batt, battery):
    """Sends `out` to the image, with the battery's report when it is due;
    when the last report went."""
    if now >= last_batt + BATTERY_S:
        out += frame(PM_BATTERY_STATE, battery)
        stats['battery'] += 1
        last_batt = now
    if out:
        link.setblocking(True)
        link.sendall(out)
        link.setblocking(False)
    return last_batt


def relay(link, udp, vbat):
    """The link as it is on a bench: every client packet goes up at once."""
    dec = Decoder()
    client = None
    stats = {'uplink': 0, 'polls': 0, 'downlink': 0, 'ready': 0, 'battery': 0, 'other': 0}
    last_up = last_batt = 0.0
    empty = 0  # polls in a row with no downlink after them
    answered = False  # a downlink packet since the last uplink
    battery = struct.pack('<Bff', 0, vbat, 0.0)
    try:
        while True:
            now = time.monotonic()
            poll_s = IDLE_POLL_S if empty >= EMPTY_POLLS else POLL_S
            timeout = max(0.0, min(last_up + poll_s, last_batt + BATTERY_S) - now)
            r, _, _ = select.select([link, udp], [], [], timeout)
            out = bytearray()
            if udp in r:
                for data, client in from_client(udp):
                    out += frame(RADIO_RAW, data)
                    stats['uplink'] += 1
            if link in r:
                down = from_image(link, dec, out, stats)
                if down is None:
                    break
                for payload in down:
                    answered = True
                    if client is not None:
                        udp.sendto(payload, client)
            now = time.monotonic()
            poll = not out and now >= last_up + (IDLE_POLL_S if empty >= EMPTY_POLLS else POLL_S)
            if out or poll:
                # What followed the previous uplink decides the next poll's pace.
                empty = 0 if answered else min(empty + 1, EMPTY_POLLS)
                answered = False
                last_up = now
            if poll:
                out += frame(RADIO_RAW, NULL_PACKET)
                stats['polls'] += 1
            last_batt = to_image(link, out, stats, now, last_batt, battery)
    except (KeyboardInterrupt, ConnectionError):
        pass
    stats['bad_frames'] = dec.bad
    return stats


def relay_radio(link, udp, vbat, spec):
    """The link over a modelled radio (`--radio`): one send at a time, as
    cflib's radio driver makes them, each through `fctools.radio`."""
    cfg = radio.parse(spec)
    air = radio.Air(cfg['drop'], cfg['burst'], cfg['seed'])
    prx = radio.Prx()
    ptx = radio.Ptx(prx, air, safelink=cfg['safelink'])
    t0 = time.monotonic()
    ptx.start(0.0)
    dec = Decoder()
    client = None
    stats = {'uplink': 0, 'polls': 0, 'downlink': 0, 'to_client': 0, 'ready': 0, 'battery': 0, 'other': 0}
    pending = collections.deque()  # the client's packets, not yet sent (cflib's out queue)
    current = None  # the packet being sent, until acknowledged
    last_send = last_batt = retry_at = 0.0
    empty = 0  # sends in a row whose acknowledgement carried nothing
    battery = struct.pack('<Bff', 0, vbat, 0.0)
    try:
        while True:
            now = time.monotonic()
            if current is not None:
                wake = retry_at
            elif pending:
                wake = last_send + radio.SEND_S
            else:
                wake = last_send + (IDLE_POLL_S if empty >= EMPTY_POLLS else POLL_S)
            timeout = max(0.0, min(wake, last_batt + BATTERY_S) - now)
            r, _, _ = select.select([link, udp], [], [], timeout)
            out = bytearray()
            if udp in r:
                for data, client in from_client(udp):
                    pending.append(data)
            if link in r:
                down = from_image(link, dec, out, stats)
                if down is None:
                    break
                for payload in down:
                    prx.queue(payload)
            now = time.monotonic()
            if now >= wake:
                if current is None:
                    current = pending.popleft() if pending else NULL_PACKET
                ok, down = ptx.send(current, now - t0)
                for p in ptx.delivered:
                    out += frame(RADIO_RAW, p)
                    stats['polls' if p[0] & 0xF3 == 0xF3 and len(p) == 1 else 'uplink'] += 1
                ptx.delivered.clear()
                if ok:
                    current = None
                    last_send = now
                    if down is not None and client is not None:
                        udp.sendto(down, client)
                        stats['to_client'] += 1
                    empty = 0 if down is not None else min(empty + 1, EMPTY_POLLS)
                elif ptx.fails == 0:
                    # cflib's driver has given up on this packet: its link error.
                    print(f'nrf51_bridge: {radio.DRIVER_RETRIES} sends in a row not acknowledged: '
                          f'"Too many packets lost" (cflib\'s link error); the packet is dropped',
                          file=sys.stderr, flush=True)
                    current = None
                    last_send = now
                else:
                    retry_at = now + radio.FAILED_SEND_S
            last_batt = to_image(link, out, stats, now, last_batt, battery)
    except (KeyboardInterrupt, ConnectionError):
        pass
    stats['bad_frames'] = dec.bad
    stats['radio'] = {'spec': spec, 'safelink': ptx.safelink, 'on_air': air.sent, 'lost_on_air': air.lost_count,
                      **ptx.counts, **prx.counts}
    return stats


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--syslink', default='127.0.0.1:19880', help="the image's USART6 (TCP)")
    ap.add_argument('--listen', default='127.0.0.1:19850', help="where cflib's udp:// driver sends")
    ap.add_argument('--vbat', type=float, default=3.9, help='battery voltage reported, V')
    ap.add_argument('--wait', type=float, default=30.0, help='how long to wait for the image, s')
    ap.add_argument('--radio', metavar='SPEC', help='model the radio, losing packets (e.g. drop=0.3,seed=1)')
    ap.add_argument('--self-test', action='store_true',
                    help="check the radio's model against itself on a lossy air, then stop")
    a = ap.parse_args()
    if a.self_test:
        from measure import record
        results, figures = radio.self_test()
        for key, value in figures.items():
            record(f'radio_selftest_{key}', value, 'packets', 'tools/nrf51_bridge.py --self-test')
        for ok, what in results:
            print(('  ok   ' if ok else '  FAIL ') + what)
        failed = sum(not ok for ok, _ in results)
        print(f'radio check: {len(results) - failed} passed, {failed} failed')
        sys.exit(1 if failed else 0)
    if not 0.0 < a.vbat < 10.0:
        sys.exit(f'nrf51_bridge: --vbat {a.vbat} is out of range (0, 10) V')
    if a.radio:
        try:
            radio.parse(a.radio)
        except ValueError as e:
            sys.exit(f'nrf51_bridge: --radio: {e}')

    link = connect(a.syslink, a.wait)
    host, port = a.listen.rsplit(':', 1)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind((host, int(port)))
    udp.setblocking(False)
    print(f'nrf51_bridge: syslink on {a.syslink}, cflib on udp://{a.listen}'
          + (f', over a modelled radio ({a.radio})' if a.radio else ''), file=sys.stderr, flush=True)
    stats = relay_radio(link, udp, a.vbat, a.radio) if a.radio else relay(link, udp, a.vbat)
    print(json.dumps(stats), flush=True)


if __name__ == '__main__':
    main()
