#!/usr/bin/env python3
"""cflib (PyPI, unmodified) flies `sil-host crtp` through its public API only.

Checked against the plant's truth (the `--truth-to` stream), not against what
the firmware says of itself:

1. `SyncCrazyflie('udp://...').open_link()` reaches fully connected (both
   TOCs and every parameter value downloaded);
2. a parameter set and read back; a refused write reads back unchanged;
   `ctl.ID` is a `uint8_t`: cflib refuses 5.05, the vehicle an unknown id;
3. a `SyncLogger` of stateEstimate.x/y/z at 100 Hz: rate, timestamps, and the
   estimate within 3 cm of the truth;
4. arm (supervisor); `takeoff(0.5, 2)`, `go_to(1, 0.5, 0.8, 0, 3)`,
   `land(0, 2)`: the truth within 5 cm of each goal, landed (motors off) at
   the end;
5. cflib's own examples, unchanged, from cflib's PyPI source distribution
   (the installed version), with CFLIB_URI set: logging/basiclog_sync.py,
   logging/basiclog.py, parameters/basicparam.py,
   step-by-step/sbs_connect_log_param.py;
6. a second session with `--position-source external`: `send_extpos` of the
   mocap stream is the only position source; `send_position_setpoint` climbs
   and moves, the truth within 5 cm of each set-point; then
   `send_notify_setpoint_stop` and the high-level `land`;
7. a session whose IMU answers NaN for 30 ms in a 1 m hover
   (`sil-host crtp --imu-dead`): the vehicle flies the last good sample for
   10 ms, then says "failsafe descent" on the console and lands straight
   down; the samples are counted (sil-host's summary, the image's log).
7b. (SIL only) the motion capture silent for 1.5 s in a 1 m hover, then one
   fix 5 m off (`sil-host crtp --fix-outage`, `--fix-outlier-at`): the truth
   within 5 cm of the hover throughout; the estimator's counts printed.
8. cflib's `autonomy/autonomous_sequence_high_level.py`, unchanged: it
   uploads its figure-8 (ten Poly4D pieces) into the trajectory memory
   (port mem), defines it, arms, takes off and flies it relative to where
   it is; the truth against the path its pieces describe, worst and RMS
   over the whole of it (≤ 4 cm worst, 2 cm RMS); then again with its
   `--relative-yaw` (a take-off turning to 3.14 / 2 rad, the figure-8
   turned by as much). On the images, whose emulation runs slower than the
   wall clock the example sleeps on, its own upload and its sequence (both
   forms) on the vehicle's clock.
9. (SIL only) cflib's `step-by-step/sbs_motion_commander.py`, unchanged:
   without a deck it stops at its Flow deck check, as on a Crazyflie; with
   `sil-host crtp --deck bcFlow2` (the flag only: a stand-in, the position
   still the SIL's motion capture) it takes off to 0.5 m, hovers and lands,
   the truth within 5 cm over the hover.
10. (SIL only) cflib's `step-by-step/sbs_swarm.py` with only its URIs changed
   (four `udp://` ports for its four radio addresses), against `sil-host
   crtp --count 4`: four vehicles in one world, each its own flight stack
   and port; its light check (`led.bitmask`), estimator resets, take-off,
   three relative moves each and landing, each vehicle's truth within 5 cm
   of every corner; the least distance between two recorded, no collision.
11. the uploaded figure-8 again, on the same link a client asking as fast
   as cflib's queues carry it: parameter reads, both TOCs downloaded again
   and again, a log block at 100 Hz; every read answered, every TOC whole,
   the figure-8 within session 5's bounds (on the images: the steps, holds
   and stack checked as every session's).

With `--qemu` the same sessions fly the `firmware-crtp` image in QEMU
(`sil-host crtp --target qemu`): cflib reaches it through
`tools/nrf51_bridge.py`, which plays the Crazyflie's nRF51 radio (syslink on
the image's USART6); the plant feeds its sensors on USART1. With
`--qemu-crazyflie` they fly the Crazyflie 2.1 image instead (`--target
qemu-crazyflie`: linked at 0x0800_4000, booted by QEMU's stand-in for the
bootloader, its motors on TIM2/TIM4).

With `--radio SPEC` (and `--qemu` or `--qemu-crazyflie`) one session only,
R, over the bridge's modelled radio losing packets (`nrf51_bridge.py
--radio`, `fctools.radio`), on ports of its own (19950, 19970, 19980):
connected, a parameter set and read back, a log block at 100 Hz, the
figure-8 uploaded, read back byte for byte from the trajectory memory and
flown within session 5's bounds; the radio's counts checked (packets lost,
the duplicates its retries made dropped by the nRF51, no link error).

Prints `crtp check: N passed, M failed` (`crtp-qemu check: ...` with --qemu,
`crtp-qemu-crazyflie check: ...` with --qemu-crazyflie, `-radio` added with
--radio); exits 1 on any failure.
Usage: crtp_cflib.py SIL_HOST [--qemu | --qemu-crazyflie] [--radio SPEC] [sil-host crtp options]
"""
import importlib.metadata
import importlib.util
import itertools
import json
import math
import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time

import cflib.crtp
from cflib.crazyflie import Crazyflie
from cflib.crazyflie.log import LogConfig
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie
from cflib.crazyflie.syncLogger import SyncLogger

from children import EndsWithFlight
from fctools.checks import Checks
from fctools.image_log import TIMING_FIELDS, link_hold, stack
from fctools.image_log import timing as image_timing
from fctools.pieces import cflib_examples
from fctools.truth import Truth, position_of
from measure import budgets, record

# --radio SPEC: the sessions of `session_radio` only, on the images, over
# the bridge's modelled radio (tools/fctools/radio.py), on ports of their
# own (another lane's cflib sessions may run beside them).
RADIO = sys.argv[sys.argv.index('--radio') + 1] if '--radio' in sys.argv[2:-1] else None
PORT = 19950 if RADIO else 19850
TRUTH_PORT = 19970 if RADIO else 19870
URI = f'udp://127.0.0.1:{PORT}'
TOL_M = 0.05
# The uploaded figure-8 flown (session 5): the truth's distance from the
# path its pieces describe, either way, worst and RMS over the whole of it.
# The MPC previews it over its horizon: without that preview (extrapolating
# the set-point of the step) it flew 4.7-4.9 cm worst, 2.6-2.7 cm RMS.
TRAJ_TOL_M = 0.04
TRAJ_RMS_TOL_M = 0.02
# Session 7's velocity and hover moves: checked this long after each ends, s.
MOTION_SETTLE_S = 3.0
# Session 4's dead IMU: when (plant time, s) and for how long.
DEAD_AT_S = 8.0
DEAD_S = 0.03
# Session 3b's motion capture: silent from (plant time, s) for how long, then
# one fix 5 m off at.
FIX_OUT_AT_S = 8.0
FIX_OUT_S = 1.5
FIX_OUTLIER_AT_S = 11.0
CRAZYFLIE = '--qemu-crazyflie' in sys.argv[2:]
QEMU = '--qemu' in sys.argv[2:] or CRAZYFLIE
CONTROLLER = [a for a in sys.argv[2:] if a not in ('--qemu', '--qemu-crazyflie', '--radio', RADIO)]
SYSLINK = '127.0.0.1:19980' if RADIO else '127.0.0.1:19880'
BRIDGE = pathlib.Path(__file__).resolve().parent / 'nrf51_bridge.py'

LABEL = ('-qemu-crazyflie' if CRAZYFLIE else '-qemu' if QEMU else '') + ('-radio' if RADIO else '')
# Each --radio session's bridge counts (fctools.radio's).
RADIOS = []
check = Checks(f'crtp{LABEL}')
# Each QEMU session's (worst data-ready -> answer instructions, late steps,
# steps passed during a design).
TIMINGS = []
# Each QEMU session's stack high-water marks (boot, tasks), bytes.
STACKS = []
# Each QEMU session's longest hold of the vehicle by the link's task, instructions.
HOLDS = []


class Sil:
    """`sil-host crtp`, and with --qemu the nRF51 bridge in front of the image."""

    def __init__(self, sil_host, *extra, truth=None):
        if truth:
            truth.reset()  # the previous session's clock is not this one's
        image = 'qemu-crazyflie' if CRAZYFLIE else 'qemu'
        target = ['--target', image, '--syslink', SYSLINK] if QEMU else []
        self.sil = subprocess.Popen([sil_host, 'crtp', *CONTROLLER, *target, '--listen', f'127.0.0.1:{PORT}',
                                     '--truth-to', f'127.0.0.1:{TRUTH_PORT}', '--duration', '120', *extra],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.bridge = None
        if QEMU:
            self.bridge = subprocess.Popen([sys.executable, str(BRIDGE), '--syslink', SYSLINK, '--listen',
                                            f'127.0.0.1:{PORT}', *(['--radio', RADIO] if RADIO else [])],
                                           stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                           text=True)
            # The image is up once its parameters are written (sil-host says so).
            deadline = time.time() + 60
            while time.time() < deadline and self.sil.poll() is None:
                line = self.sil.stderr.readline()
                if 'parameters written' in line:
                    break
        # sil-host ending before `stop` (no image to run, a crash) ends this
        # script at once, its bridge stopped: cflib would wait on the radio.
        self.watch = EndsWithFlight(self.sil, "sil-host crtp", others=[self.bridge])
        # sil-host's stderr, drained (a full pipe would stall it) and kept.
        self.err = []
        threading.Thread(target=self._drain, daemon=True).start()
        time.sleep(0.5)

    def _drain(self):
        try:
            for line in self.sil.stderr:
                self.err.append(line)
        except (ValueError, OSError):
            pass  # `stop` closed the pipe: sil-host has ended

    def stop(self):
        """Stops both (sil-host stops its QEMU on SIGTERM); returns sil-host's
        summary and the bridge's line."""
        self.watch.done()
        self.sil.terminate()
        try:
            out, _ = self.sil.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.sil.kill()
            out, _ = self.sil.communicate()
        out += ''.join(self.err[-20:])
        bridge = ''
        if self.bridge:
            # It ends when QEMU closes USART6; SIGINT is its Ctrl-C otherwise.
            try:
                bridge, _ = self.bridge.communicate(timeout=5)
            except subprocess.TimeoutExpired:
                self.bridge.send_signal(signal.SIGINT)
                bridge, _ = self.bridge.communicate()
        return out, bridge


def report(sil, failed_before):
    """Stops the session; when one of its checks failed, shows what sil-host
    (its summary, with the image's log in QEMU) and the bridge said."""
    out, bridge = sil.stop()
    if QEMU:
        print(f'  the bridge relayed: {bridge.strip()}')
    if RADIO:
        counts = json.loads(bridge.strip().splitlines()[-1]).get('radio', {}) if bridge.strip() else {}
        RADIOS.append(counts)
        air, lost = counts.get('on_air', 0), counts.get('lost_on_air', 0)
        dups = counts.get('retransmits', 0) + counts.get('duplicates', 0)
        want = radio_spec()['drop']
        check(counts.get('safelink') and air > 0 and lost >= 0.5 * want * air and dups > 0
              and counts.get('link_errors', 1) == 0,
              f'the radio ({RADIO}) lost {lost} of {air} packets on the air ({100 * lost / max(air, 1):.1f} %); '
              f'the dongle sent {counts.get("sends", 0)} times, {counts.get("not_acked", 0)} not acknowledged and '
              f'sent again; the {dups} duplicates its retries made were dropped by the nRF51 (PID '
              f'{counts.get("retransmits", 0)}, safelink {counts.get("duplicates", 0)}), '
              f'{counts.get("resent_down", 0)} downlink packets carried again; '
              f'{counts.get("link_errors")} link errors (cflib\'s "Too many packets lost")')
    if QEMU:
        # The image's tasks measure every step (fc_stm32f405::timing) and log
        # the figures every 1000 steps and at once when a deadline is missed.
        t = image_timing(out)
        steps, est, ans, deadline, late, jobs, answers, tx, imu, lent = \
            (t[k] for k in TIMING_FIELDS) if t else (0,) * 8 + (-1, 0)
        check(steps >= 1000 and imu == 0 and jobs + answers + tx == 0,
              f'the image met every IMU deadline at 1 kHz: {imu} of {steps} samples estimated late (worst data-ready '
              f'-> estimate {est} instructions, deadline {deadline}: 168 000 cycles at CPI 1.5 x 1.5), no step dropped')
        # Every step, a re-design's included (its controller lent to the
        # link's task, the step answered with the motors off), is answered
        # within the image step's budget: one 1 kHz period at CPI 1.5 with a
        # 1.5 margin (firmware/stm32f405/src/budgets.rs).
        budget = budgets()['budget_image_step_instructions']
        check(steps >= 1000 and late == 0 and ans <= budget,
              f'the controller answered every step within the 1 kHz budget: {late} late of {steps}, worst '
              f'data-ready -> outputs driven {ans} instructions (budget {budget}: 168 000 cycles at CPI 1.5 x 1.5), '
              f'{lent} steps passed with the motors off during a design')
        TIMINGS.append((ans, late, lent))
        # The image paints its stack at boot, logs the boot's mark, paints it
        # again and logs the tasks' mark (every task's frames, nested) with
        # its timing line (fc_stm32f405::stack).
        boot, tasks, capacity = stack(out)
        budget = budgets()['budget_image_stack_bytes']
        check(0 < boot <= budget and 0 < tasks <= budget,
              f'the image\'s stack reached {boot} B at boot and {tasks} B in its tasks, of the {capacity} B '
              f'it may grow to (budget {budget} B)')
        STACKS.append((boot, tasks))
        # The link's task holds the vehicle while it handles a packet; a
        # sample ready meanwhile waits, and its data-ready is stamped only
        # once its task runs: that wait is not in the figures above. Held
        # to its budget here with the radio's bytes that land in it (QEMU
        # delivers them unpaced); the sum with the worst step, below.
        held = link_hold(out)
        hold_budget = budgets()['budget_link_hold_instructions']
        check(0 < held <= hold_budget, f'the image timed the link\'s holds of the vehicle: up to {held} '
                                       f'instructions, the radio\'s interrupts in them apart (budget {hold_budget})')
        HOLDS.append(held)
    if QEMU:
        check('storage: a 2 KiB RAM stand-in' in out,
              'the image names what keeps its settings: a RAM stand-in (QEMU models no flash controller)')
    if QEMU:
        # QEMU models no IWDG (its registers read 0): what can be seen here is
        # that each image started it once both tasks ran, and that no update
        # of its timeout (widened for a re-design) failed.
        check('IWDG started' in out and 'ERROR IWDG' not in out,
              'the image started its IWDG once the IMU task and the controller ran')
    if QEMU and not CRAZYFLIE:
        # firmware-crtp logs TIM3's four compare values (duty = commanded
        # rotor speed / Ωmax) when its motors start or stop and once a second
        # while they run. At hover the four are alike and the rotors turn
        # well inside their range; landed, every output is 0.
        tim3 = [(tuple(int(x) for x in m.group(1).split(',')), int(m.group(2)))
                for m in re.finditer(r'motors: TIM3 compare \[([0-9, ]+)\] of reload (\d+)', out)]
        running = [c for c, _ in tim3 if min(c) > 0]
        hover = [c for c, r in tim3 if min(c) >= 0.2 * r and max(c) <= 0.8 * r and max(c) - min(c) <= 0.1 * r]
        check(len(running) >= 3 and len(hover) >= 1 and all(r == 52_499 and max(c) <= r for c, r in tim3)
              and tim3 and tim3[-1][0] == (0, 0, 0, 0),
              f'firmware-crtp drove TIM3 (400 Hz, reload 52499): {len(running)} compare sets logged armed, '
              f'{len(hover)} at hover (e.g. {hover[:1]}), the last (landed) {tim3[-1][0] if tim3 else None}')
    if CRAZYFLIE:
        # The image logs, once a second armed, the four TIM2/TIM4 compares the
        # thrust curve gave. Hovering rotorpy's 30 g Crazyflie takes 74 mN a
        # rotor: 2.4 V at the motor, compare ≈ 147 of 255 at 4.2 V.
        sets = [tuple(int(x) for x in m.group(1).split(','))
                for m in re.finditer(r'motors: compare \[([0-9, ]+)\]', out)]
        hover = [c for c in sets if all(120 <= x <= 175 for x in c) and max(c) - min(c) <= 20]
        check(len(sets) >= 3 and len(hover) >= 1 and all(max(c) <= 255 for c in sets),
              f'the Crazyflie image drove TIM2/TIM4: {len(sets)} compare sets logged armed, '
              f'{len(hover)} at hover (e.g. {hover[:1]})')
    if check.failed > failed_before:
        print(f'sil-host said:\n{out[-4000:]}\nthe bridge said: {bridge.strip()}')
    return out


def near(truth, goal, what):
    p = truth.pos
    err = math.dist(p, goal)
    check(err <= TOL_M, f'{what}: truth ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) is {100 * err:.1f} cm '
          f'from ({goal[0]}, {goal[1]}, {goal[2]}) (bound {100 * TOL_M:.0f} cm)')


def connect():
    """open_link, then cflib's own `fully_connected` (TOCs and every value in)."""
    cf = Crazyflie(rw_cache=None)
    full = threading.Event()
    cf.fully_connected.add_callback(lambda uri: full.set())
    scf = SyncCrazyflie(URI, cf=cf)
    t0 = time.time()
    scf.open_link()
    check(full.wait(10), f'fully connected in {time.time() - t0:.2f} s')
    return scf


def read_back(cf, name, want, within_s=None, ask=False):
    """`name`'s value once it reads `want`, or its last read after `within_s`
    s of wall time (5 s in process, 30 s on an image). A write that
    re-designs is answered once the design is done, on an image by its
    lowest-priority task in the time the steps leave it: in lockstep with
    the plant, the steps that pass meanwhile depend on how fast the machine
    runs QEMU against sil-host (1 100 to 10 400 of them in the first
    session, on one machine). cflib's value is the one it last heard: `ask`
    asks the vehicle again each time (a write under another name)."""
    end = time.monotonic() + (within_s or (30.0 if QEMU else 5.0))
    while True:
        if ask:
            cf.param.request_param_update(name)
            time.sleep(0.05)
        value = float(cf.param.get_value(name))
        if abs(value - want) < 1e-6 or time.monotonic() > end:
            return value
        time.sleep(0.05)


def log_estimate(scf, truth, n=100):
    """A `SyncLogger` of stateEstimate.x/y/z at 100 Hz for `n` samples: their
    timestamps (ms) and each estimate's distance from the truth (m)."""
    lg = LogConfig('position', 10)
    for v in 'xyz':
        lg.add_variable(f'stateEstimate.{v}', 'float')
    stamps, errs = [], []
    with SyncLogger(scf, lg) as log:
        for ts, data, _ in log:
            stamps.append(ts)
            est = (data['stateEstimate.x'], data['stateEstimate.y'], data['stateEstimate.z'])
            errs.append(math.dist(est, truth.pos))
            if len(stamps) == n:
                break
    return stamps, errs


def estimator_settled(scf):
    """cflib's own recipe (its autonomous examples): kalman.varP* spread under 1e-3."""
    lg = LogConfig('kalman', 10)
    for v in ('varPX', 'varPY', 'varPZ'):
        lg.add_variable(f'kalman.{v}', 'float')
    hist = []
    deadline = time.time() + 10
    with SyncLogger(scf, lg) as log:
        for _, data, _ in log:
            hist.append([data[f'kalman.{v}'] for v in ('varPX', 'varPY', 'varPZ')])
            hist = hist[-10:]
            if len(hist) == 10 and all(max(c) - min(c) < 0.001 for c in zip(*hist)):
                return True
            if time.time() > deadline:
                return False


def session_high_level(sil_host, truth):
    print('session 1: the SIL\'s motion capture, the high-level commander')
    failed_before = check.failed
    sil = Sil(sil_host, truth=truth)
    try:
        scf = connect()
        cf = scf.cf
        check(cf.platform.get_protocol_version() == 12 and cf.param.is_updated,
              f'protocol {cf.platform.get_protocol_version()}, '
              f'{sum(len(g) for g in cf.param.toc.toc.values())} params (all values read), '
              f'{sum(len(g) for g in cf.log.toc.toc.values())} log variables')
        before = float(cf.param.get_value('mpc.W_POS'))
        cf.param.set_value('mpc.W_POS', before * 2)
        after = read_back(cf, 'mpc.W_POS', before * 2)
        check(abs(after - 2 * before) < 1e-6, f'param mpc.W_POS set to {2 * before} reads back {after}')
        cf.param.set_value('veh.MASS', -1.0)
        time.sleep(0.3)
        mass = float(cf.param.get_value('veh.MASS'))
        check(abs(mass - 0.03) < 1e-6, f'a refused write (veh.MASS = -1) reads back the value in force, {mass}')
        # Integers are typed as such in the TOC: cflib reads ctl.ID as an
        # integer and refuses a fraction itself; a controller id no
        # controller has is refused by the vehicle, and reads back unchanged.
        elem = cf.param.toc.get_element_by_complete_name('ctl.ID')
        ctl = cf.param.get_value('ctl.ID')
        try:
            cf.param.set_value('ctl.ID', '5.05')
            sent = True
        except ValueError:
            sent = False
        cf.param.set_value('ctl.ID', 250)
        time.sleep(0.3)
        check(elem.ctype == 'uint8_t' and ctl.isdigit() and not sent and cf.param.get_value('ctl.ID') == ctl,
              f'ctl.ID is a {elem.ctype} ({ctl}); cflib refuses 5.05, the vehicle refuses 250: reads back {ctl}')
        # The Crazyflie's own names are the same parameters (the table's
        # aliases): stabilizer.controller is ctl.ID, pid_attitude.* the PD's
        # attitude gains; a write under one name reads back under the other.
        kd = float(cf.param.get_value('pd.YAW_D'))
        cf.param.set_value('pid_attitude.yaw_kd', kd * 2)
        alias = read_back(cf, 'pd.YAW_D', kd * 2, ask=True)
        cf.param.set_value('pd.YAW_D', kd)
        restored = read_back(cf, 'pid_attitude.yaw_kd', kd, ask=True)
        check(cf.param.get_value('stabilizer.controller') == ctl
              and alias == 2 * kd and restored == kd,
              f'stabilizer.controller reads ctl.ID ({ctl}); pid_attitude.yaw_kd = {2 * kd:g} '
              f'reads back as pd.YAW_D = {alias:g}, and back to {restored:g}')
        # cflib's persistent parameters: stored where the vehicle keeps them
        # (in QEMU a RAM stand-in, which its boot log names), then cleared;
        # in process without --storage there is nowhere to keep them (EIO).
        ok = persistent(cf, 'store', 'mpc.W_POS')
        state = persistent(cf, 'get_state', 'mpc.W_POS')
        cleared = persistent(cf, 'clear', 'mpc.W_POS')
        state2 = persistent(cf, 'get_state', 'mpc.W_POS')
        if QEMU:
            # (the image's default is its boot value, before sil-host writes the vehicle's)
            check(ok is True and state and state.is_stored and abs(state.stored_value - after) < 1e-6
                  and cleared is True and state2 and not state2.is_stored,
                  f'persistent_store of mpc.W_POS ({ok}): {state}; persistent_clear ({cleared}): {state2}')
        else:
            check(ok is False and cleared is False and state and not state.is_stored
                  and abs(state.default_value - before) < 1e-6,
                  f'without --storage, persistent_store and _clear fail ({ok}, {cleared}) and nothing is '
                  f'stored: {state}')

        stamps, errs = log_estimate(scf, truth)
        # cflib starts a new block twice (after its creation, then start()); the
        # second start re-phases the block's timer, as the firmware's does. A
        # block is sampled and stamped when the link's task (lowest priority)
        # sends it: on the image a step late at times (11 ms, then 9: the block
        # stays on its 10 ms grid), as the Crazyflie's log task stamps when it runs.
        gaps = sorted(b - a for a, b in itertools.pairwise(stamps))
        check(gaps[1] >= 9 and gaps[-1] <= 11 and gaps[len(gaps) // 2] == 10,
              f'SyncLogger at 100 Hz: 100 samples, timestamps 10 ms apart (gaps {gaps[0]}–{gaps[-1]} ms, '
              f'one re-phase allowed, a step of jitter)')
        check(max(errs) < 0.03, f'stateEstimate within 3 cm of the truth (worst {100 * max(errs):.2f} cm)')

        cf.supervisor.send_arming_request(True)
        time.sleep(0.3)
        check('Is armed' in cf.supervisor.read_state_list(), 'armed (supervisor state bits)')
        hl = cf.high_level_commander
        start = truth.pos
        hl.takeoff(0.5, 2.0)
        truth.sleep(3.0)
        near(truth, (start[0], start[1], 0.5), 'takeoff(0.5, 2) after 3 s')
        # A ground station flooding it with parameter reads all through the
        # go_to: cflib sends one read at a time and the next when it is
        # answered; four are kept queued, so the link is never idle.
        reads = {'asked': 0, 'answered': 0}
        cf.param.add_update_callback(group='mpc', name='W_POS',
                                     cb=lambda name, value: reads.__setitem__('answered', reads['answered'] + 1))
        flooding = threading.Event()
        flooding.set()

        def flood():
            while flooding.is_set():
                while reads['asked'] - reads['answered'] < 4:
                    cf.param.request_param_update('mpc.W_POS')
                    reads['asked'] += 1
                time.sleep(0.0005)

        flooder = threading.Thread(target=flood, daemon=True)
        hl.go_to(1.0, 0.5, 0.8, 0.0, 3.0)
        flooder.start()
        truth.sleep(4.5)
        flooding.clear()
        flooder.join()
        near(truth, (1.0, 0.5, 0.8), 'go_to(1, 0.5, 0.8, 0, 3) after 4.5 s')
        check(reads['answered'] >= 100, f'under a parameter-read flood: {reads["answered"]} reads answered '
                                        f'during the go_to ({reads["asked"]} asked)')
        hl.land(0.0, 2.0)
        truth.sleep(3.5)
        near(truth, (1.0, 0.5, 0.0), 'land(0, 2) after 3.5 s')
        check(not truth.last['flying'], 'landed: motors off')
        scf.close_link()
    finally:
        report(sil, failed_before)


def session_extpos(sil_host, truth):
    print('session 2: send_extpos as the only position source, send_position_setpoint')
    failed_before = check.failed
    sil = Sil(sil_host, '--position-source', 'external', truth=truth)
    try:
        scf = connect()
        cf = scf.cf
        feeding = threading.Event()
        feeding.set()

        def feed():
            # A motion-capture system: each truth sample (100 Hz of the plant's
            # time) forwarded as it arrives.
            last = None
            while feeding.is_set():
                sample = truth.last
                if sample is not None and sample is not last:
                    cf.extpos.send_extpos(sample['x'], sample['y'], sample['z'])
                    last = sample
                time.sleep(0.002)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        cf.param.set_value('kalman.resetEstimation', '1')
        time.sleep(0.1)
        cf.param.set_value('kalman.resetEstimation', '0')
        check(estimator_settled(scf), 'estimator converged on extpos (kalman.varP* spread < 1e-3)')
        cf.supervisor.send_arming_request(True)
        time.sleep(0.3)
        check('Is armed' in cf.supervisor.read_state_list(), 'armed on extpos')
        for goal, secs in (((0.0, 0.0, 0.5), 3.0), ((0.5, -0.3, 0.7), 4.0)):
            truth.sleep(secs, every=lambda goal=goal: cf.commander.send_position_setpoint(*goal, 0.0))
            near(truth, goal, f'send_position_setpoint{goal} for {secs:.0f} s')
        cf.commander.send_notify_setpoint_stop()
        cf.high_level_commander.land(0.0, 2.0)
        truth.sleep(3.5)
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'land after notify_setpoint_stop: z {truth.last["z"]:.3f} m, motors off')
        feeding.clear()
        feeder.join()
        scf.close_link()
    finally:
        report(sil, failed_before)


def hover_at_1m(scf, truth, fault_at_s, what):
    """Estimator converged, armed, `takeoff(1.0, 2)` and 3 s (plant time):
    checked hovering at 1 m at least 0.5 s before `fault_at_s`; where."""
    cf = scf.cf
    check(estimator_settled(scf), 'estimator converged')
    cf.supervisor.send_arming_request(True)
    time.sleep(0.3)
    cf.high_level_commander.takeoff(1.0, 2.0)
    truth.sleep(3.0)
    hover = truth.pos
    check(truth.t < fault_at_s - 0.5 and abs(hover[2] - 1.0) < 0.1,
          f'hovering at {hover[2]:.2f} m before {what} at {fault_at_s} s (plant time {truth.t:.1f} s)')
    return hover


def session_dead_imu(sil_host, truth):
    print(f'session 3: the IMU answers NaN for {1000 * DEAD_S:.0f} ms in a hover (sil-host --imu-dead)')
    failed_before = check.failed
    sil = Sil(sil_host, '--imu-dead', f'{DEAD_AT_S},{DEAD_S}', truth=truth)
    said = []
    try:
        scf = connect()
        cf = scf.cf
        cf.console.receivedChar.add_callback(said.append)
        hover = hover_at_1m(scf, truth, DEAD_AT_S, 'the IMU dies')
        truth.sleep(DEAD_AT_S + 0.5 - truth.t)
        text = ''.join(said)
        check('IMU silent for more than 10 ms: failsafe descent' in text,
              'the console said: IMU silent for more than 10 ms: failsafe descent')
        # Straight down at 0.3 m/s from 1 m, then motors off.
        truth.sleep(5.0)
        p = truth.pos
        drift = math.dist(p[:2], hover[:2])
        check(p[2] < TOL_M and not truth.last['flying'] and drift < 0.1,
              f'descended and landed where it hovered: z {p[2]:.3f} m, {100 * drift:.1f} cm from the hover '
              f'point, motors off')
        check('landed: motors off' in ''.join(said), 'the console said: landed: motors off')
        scf.close_link()
    finally:
        out = report(sil, failed_before)
    # Every NaN sample counted bad, each step flown on the last good one,
    # one silence past 10 ms (in-process: sil-host's summary; the images log it).
    n = round(DEAD_S * 1000)
    if QEMU:
        m = re.findall(r'IMU: (\d+) samples missing, (\d+) bad .*?, (\d+) steps flown on the last good one, '
                       r'(\d+) silences', out)
        got = tuple(int(x) for x in m[-1]) if m else None
    else:
        m = re.search(r'"imu": \[\s*(\d+),\s*(\d+),\s*(\d+),\s*(\d+)\s*\]', out)
        got = tuple(int(x) for x in m.groups()) if m else None
    check(got is not None and got[0] == 0 and abs(got[1] - n) <= 1 and got[2] == got[1] and got[3] == 1,
          f'IMU samples (missing, bad, flown on the last good one, silences): {got}, {n} NaN samples sent')


def session_fix_faults(sil_host, truth):
    """The motion capture fails from the simulator's side in a 1 m hover
    (`sil-host crtp --fix-outage`, `--fix-outlier-at`): no fix for
    FIX_OUT_S, then one fix 5 m off. The estimator dead-reckons on the IMU
    through the outage and its gate refuses the outlier; the truth's worst
    distance from the hover over the whole window is checked and recorded."""
    print(f'session 3b: the motion capture stops for {FIX_OUT_S} s, then lies by 5 m once, in a hover '
          f'(sil-host --fix-outage, --fix-outlier-at)')
    failed_before = check.failed
    sil = Sil(sil_host, '--fix-outage', f'{FIX_OUT_AT_S},{FIX_OUT_S}', '--fix-outlier-at', f'{FIX_OUTLIER_AT_S}',
              truth=truth)
    try:
        scf = connect()
        cf = scf.cf
        hover = hover_at_1m(scf, truth, FIX_OUT_AT_S, 'the fixes stop')
        truth.sleep(FIX_OUTLIER_AT_S + 2.0 - truth.t)
        window = [p for t, p in truth.tracks.get(0, []) if FIX_OUT_AT_S <= t <= FIX_OUTLIER_AT_S + 2.0]
        worst = max((math.dist(p, hover) for p in window), default=math.inf)
        check(len(window) > 100 and worst <= TOL_M,
              f'through the outage and the outlier the truth stayed within {100 * worst:.1f} cm of the hover '
              f'over {FIX_OUT_AT_S}-{FIX_OUTLIER_AT_S + 2.0} s (bound {100 * TOL_M:.0f} cm)')
        record('crtp_sil_fix_faults_worst_m', worst, 'm', 'tools/crtp_cflib.py session 3b')
        cf.high_level_commander.land(0.0, 2.0)
        truth.sleep(3.5)
        check(truth.last['z'] < TOL_M and not truth.last['flying'], 'landed: motors off')
        scf.close_link()
    finally:
        out = report(sil, failed_before)
    # The estimator's own count (sil-host's summary), the flight's whole:
    # the outlier is among the refused (that it was not believed is the
    # truth's window above), with the lift-off's (the estimator refuses
    # centimetres at a lift-off, and resets to them after 20).
    m = re.search(r'"fixes": \[\s*(\d+),\s*(\d+),\s*(\d+)\s*\]', out)
    fused, refused, resets = (int(x) for x in m.groups()) if m else (0, 0, -1)
    check(fused > 0 and refused >= 1,
          f'position fixes over the flight: {fused} fused, {refused} refused by the estimator\'s gate, '
          f'{resets} resets to a fix (information)')


def run_example(script, timeout_s, args=()):
    """cflib's example `script` (a path under its examples), unchanged,
    against the SIL, with its command-line `args`: its completed process."""
    return subprocess.run([sys.executable, str(script), *args], check=False, env=dict(os.environ, CFLIB_URI=URI),
                          capture_output=True, text=True, timeout=timeout_s, cwd=script.parent)


def example_ran(r, script, expect, refuse=None):
    """The check that example `script` ran (`r`): exit 0, `expect` (a
    string, or several in turn) in its output (and `refuse` not)."""
    expect = (expect,) if isinstance(expect, str) else expect
    at, found = 0, True
    for e in expect:
        i = r.stdout.find(e, at)
        found, at = found and i >= 0, max(at, i + len(e))
    ok = r.returncode == 0 and found and (refuse is None or refuse not in r.stdout)
    check(ok, f'{script.name}: exit {r.returncode}, {r.stdout.count(chr(10))} lines, '
              + ', then '.join(f'"{e}"' for e in expect) + ' in its output'
              + ('' if ok else f'\n{r.stdout[-800:]}\n{r.stderr[-1500:]}'))


def session_examples(sil_host):
    version = importlib.metadata.version('cflib')
    print(f'session 4: cflib {version}\'s own examples, unchanged')
    examples = cflib_examples()
    # What each prints when it worked (its own output, unchanged).
    # sbs_connect_log_param.py writes stabilizer.estimator 2, then 1: the
    # Kalman filter is the only estimator here, so 1 is refused (said on
    # the console) and the value stays 2, which its callback prints.
    for script, expect in (('logging/basiclog_sync.py', "'stabilizer.roll'"),
                           ('logging/basiclog.py', 'pm.vbat'),
                           ('parameters/basicparam.py', 'Parameters downloaded'),
                           ('step-by-step/sbs_connect_log_param.py',
                            'The crazyflie has parameter stabilizer.estimator set at number: 2'),
                           # Every persistent parameter's state, then ring.effect
                           # set to 10, stored (its state says so), cleared.
                           ('parameters/persistent_params.py',
                            ('Persisted ring.effect!',
                             'ring.effect: PersistentParamState(is_stored=True, default_value=6, stored_value=10)',
                             'Cleared ring.effect!',
                             'ring.effect: PersistentParamState(is_stored=False, default_value=6, stored_value=None)'))):
        # A store to keep what persistent_params.py stores: a file in
        # process; the images keep theirs (a RAM stand-in in QEMU).
        store = pathlib.Path('target/cflib-example-store.bin').resolve()
        store.unlink(missing_ok=True)
        sil = Sil(sil_host, *(['--storage', str(store)] if 'persistent' in script and not QEMU else []))
        try:
            example_ran(run_example(examples / script, 60), examples / script, expect)
        finally:
            sil.stop()


def poly4d_path(rows, shift, dt=0.01, turn=0.0):
    """cflib's `Poly4D` rows (duration, then x, y, z and yaw's eight
    coefficients each, from the constant up) evaluated every `dt` s from
    the first piece's start, turned by `turn` (rad, counter-clockwise seen
    from above) about that start and moved by `shift`: the positions a
    relative start (with a relative yaw, `turn`) flies, the Crazyflie's
    frame, m, one row each `dt` s."""
    import numpy as np
    points = []
    for row in rows:
        t = np.arange(0.0, row[0], dt)
        points.append(np.stack([np.polyval(row[1 + 8 * a:9 + 8 * a][::-1], t) for a in range(3)], 1))
    p = np.concatenate(points)
    first = p[0].copy()
    c, s = math.cos(turn), math.sin(turn)
    d = p - first
    p[:, 0] = first[0] + c * d[:, 0] - s * d[:, 1]
    p[:, 1] = first[1] + s * d[:, 0] + c * d[:, 1]
    return p + np.asarray(shift)


def tracking_error(flown, path, dt=0.01):
    """The truth `flown` (rows of plant time, x, y, z) against `path` (one
    position each `dt` s from its start): the start time that fits it best
    (least squares, on the plant's clock), then the worst and the RMS
    distance over the path's whole span from there, m, and that start."""
    import numpy as np
    t = flown[:, 0]
    best = (math.inf, math.inf, None)
    span = (len(path) - 1) * dt
    for t0 in np.arange(t[0], t[-1] - span, dt):
        at = np.clip(np.round((t - t0) / dt).astype(int), 0, len(path) - 1)
        inside = (t >= t0) & (t <= t0 + span)
        err = np.linalg.norm(flown[inside, 1:] - path[at[inside]], axis=1)
        rms = float(np.sqrt(np.mean(err ** 2)))
        if rms < best[1]:
            best = (float(err.max()), rms, float(t0))
    return best


def figure8_example(name):
    """cflib's `autonomy/autonomous_sequence_high_level.py` from its source
    distribution, loaded as module `name` (only its definitions: it flies
    under `__main__`): its path and the module."""
    script = cflib_examples() / 'autonomy' / 'autonomous_sequence_high_level.py'
    spec = importlib.util.spec_from_file_location(name, script)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    return script, example


def figure8_flown(truth, example, start, since):
    """The truth's track (vehicle 0's) since plant time `since`, above
    0.5 m, against the example's figure-8 started 1 m above `start`: its
    worst and RMS distance (`tracking_error`), m; ∞ without a track."""
    import numpy as np
    flown = np.array([(t, *p) for t, p in list(truth.tracks.get(0, [])) if t >= since])
    path = poly4d_path(example.figure8, (start[0], start[1], 1.0))
    high = flown[flown[:, 3] > 0.5] if len(flown) else np.zeros((0, 4))
    worst, rms, _ = tracking_error(high, path) if len(high) > len(path) else (math.inf, math.inf, None)
    return worst, rms


def radio_tag():
    """The measurements' prefix of a --radio session, and their source."""
    image = 'crazyflie' if CRAZYFLIE else 'crtp'
    source = f'tools/crtp_cflib.py --qemu{"-crazyflie" if CRAZYFLIE else ""} --radio {RADIO}'
    return f'{image}_radio_{round(100 * radio_spec()["drop"])}', source


def fly_figure8(cf, example, truth, during=None, relative_yaw=False):
    """`autonomous_sequence_high_level.py`'s upload (its `upload_trajectory`)
    and sequence on `cf`, its durations on the vehicle's clock: reset the
    estimator, arm, take off to 1 m (with `relative_yaw`, turning to its
    3.14 / 2 rad), fly the figure-8 from where it is (and turned as it
    heads), land. `during()` is called as the trajectory starts; the
    trajectory's duration, s."""
    from cflib.utils.reset_estimator import reset_estimator
    duration = example.upload_trajectory(cf, 1, example.figure8)
    reset_estimator(cf)
    cf.supervisor.send_arming_request(True)
    truth.sleep(1.0)
    cf.high_level_commander.takeoff(1.0, 2.0, yaw=3.14 / 2 if relative_yaw else 0.0)
    truth.sleep(3.0)
    cf.high_level_commander.start_trajectory(1, 1.0, relative_position=True, relative_yaw=relative_yaw)
    if during:
        during()
    truth.sleep(duration)
    cf.high_level_commander.land(0.0, 2.0)
    truth.sleep(2.0)
    cf.high_level_commander.stop()
    return duration


class Flood:
    """A client that asks as fast as cflib's own queues carry it, on one
    link: parameter reads (cflib's updater: one in flight, resent until
    answered) kept `depth` ahead of their answers, the parameter and log
    TOCs downloaded again and again (cflib's `TocFetcher`, item by item,
    each resent until answered, into TOCs of its own), and a log block of
    the estimate at 100 Hz."""

    def __init__(self, cf, depth=8):
        from cflib.crazyflie.log import LogTocElement
        from cflib.crazyflie.param import ParamTocElement
        self.cf, self.depth = cf, depth
        self.names = [f'{g}.{n}' for g, entries in cf.param.toc.toc.items() for n in entries]
        self.kinds = ((ParamTocElement, 2, len(self.names)),
                      (LogTocElement, 5, sum(len(e) for e in cf.log.toc.toc.values())))
        self.asked = self.answered = 0
        self.tocs = [0, 0]  # whole TOCs downloaded: param, log
        self.short = []  # TOCs that came with fewer entries than the vehicle's
        self.samples = []  # the log block's timestamps, ms
        self.running = threading.Event()
        cf.param.add_update_callback(cb=self._answered)
        self.log = LogConfig(name='Flood', period_in_ms=10)
        for v in ('stateEstimate.x', 'stateEstimate.y', 'stateEstimate.z'):
            self.log.add_variable(v, 'float')
        cf.log.add_config(self.log)
        self.log.data_received_cb.add_callback(lambda ts, data, conf: self.samples.append(ts))

    def _answered(self, name, value):
        if self.running.is_set() or self.asked > self.answered:
            self.answered += 1

    def _tocs(self):
        """Downloads the two TOCs in turn, each once the last is whole (a
        fetcher started from another's callback is handed that one's last
        answer as its first: cflib's TocFetcher reads any packet then as
        the TOC's size)."""
        from cflib.crazyflie.toc import Toc, TocFetcher
        from cflib.crazyflie.toccache import TocCache
        k = 0
        while self.running.is_set():
            element, port, want = self.kinds[k]
            toc, done = Toc(), threading.Event()
            TocFetcher(self.cf, element, port, toc, done.set, TocCache()).start()
            if not done.wait(30):
                self.short.append((port, 'no answer in 30 s'))
                return
            got = sum(len(e) for e in toc.toc.values())
            self.tocs[k] += 1
            if got != want:
                self.short.append((port, got))
            k = 1 - k

    def start(self):
        """Starts the flood: the log block, the TOCs' downloads, the reads."""
        self.running.set()
        self.log.start()
        threading.Thread(target=self._tocs, daemon=True).start()
        threading.Thread(target=self._reads, daemon=True).start()

    def _reads(self):
        i = 0
        while self.running.is_set():
            if self.asked - self.answered < self.depth:
                self.cf.param.request_param_update(self.names[i % len(self.names)])
                self.asked += 1
                i += 1
            else:
                time.sleep(0.001)

    def stop(self, wait_s):
        """Stops asking; waits up to `wait_s` (wall) for the reads asked to
        be answered."""
        self.running.clear()
        end = time.time() + wait_s
        while self.answered < self.asked and time.time() < end:
            time.sleep(0.05)
        self.log.stop()


def session_flood(sil_host, truth):
    """The uploaded figure-8 flown (as session 5 flies it on the images)
    while a client asks for parameters, TOCs and logs as fast as the link
    carries them ([`Flood`]): every read answered, every TOC whole, the log
    block's samples counted; on the images the steps, the link's holds and
    the stack under that load (`report`), and the figure-8 within session
    5's bounds."""
    import numpy as np
    print('session 11: the uploaded figure-8 flown under a flood of parameter reads, TOC downloads and a log block')
    failed_before = check.failed
    _, example = figure8_example('cflib_example_figure8_flood')
    sil = Sil(sil_host, truth=truth)
    try:
        while truth.last is None:
            time.sleep(0.05)
        start, since = truth.pos, truth.t
        scf = connect()
        flood = Flood(scf.cf)
        t_flood = []
        duration = fly_figure8(scf.cf, example, truth, during=lambda: (flood.start(), t_flood.append(truth.t)))
        t_flood.append(truth.t)
        flood.stop(30.0)
        span_s = t_flood[1] - t_flood[0]
        check(flood.asked > 0 and flood.answered == flood.asked,
              f'{flood.answered} of {flood.asked} parameter reads answered over the {span_s:.1f} s of vehicle time '
              f'the flood lasted ({flood.asked / max(span_s, 1e-9):.0f} a second, {flood.depth} queued ahead)')
        check(min(flood.tocs) >= 1 and not flood.short,
              f'the TOCs downloaded whole meanwhile: parameters {flood.tocs[0]} times, log {flood.tocs[1]} times'
              + (f'; short: {flood.short}' if flood.short else ''))
        ts = np.array(flood.samples, dtype=float)
        gaps = np.diff(ts) if len(ts) > 1 else np.array([math.inf])
        print(f'  the log block (10 ms): {len(ts)} samples, {len(ts) / max(span_s, 1e-9):.0f} a second of vehicle '
              f'time, longest gap {gaps.max():.0f} ms (information: the Crazyflie drops log data its queue '
              f'cannot take, by design)')
        scf.close_link()
        truth.sleep(0.5)
        worst, rms = figure8_flown(truth, example, start, since)
        check(worst <= TRAJ_TOL_M and rms <= TRAJ_RMS_TOL_M,
              f'the figure-8 ({duration:.1f} s) under the flood: worst {100 * worst:.1f} cm, RMS {100 * rms:.1f} cm '
              f'(bounds {100 * TRAJ_TOL_M:.0f} and {100 * TRAJ_RMS_TOL_M:.0f} cm, as session 5)')
    finally:
        report(sil, failed_before)
    if QEMU and TIMINGS and HOLDS:
        # This session's own figures (report's last): its worst step, late
        # steps and longest hold under the flood.
        image = 'crazyflie' if CRAZYFLIE else 'crtp'
        source = f'tools/crtp_cflib.py --qemu{"-crazyflie" if CRAZYFLIE else ""} (session 11)'
        record(f'{image}_qemu_flood_answer_worst_icount', TIMINGS[-1][0], 'instructions', source)
        record(f'{image}_qemu_flood_late_steps', TIMINGS[-1][1], 'steps', source)
        record(f'{image}_qemu_flood_link_hold_worst_icount', HOLDS[-1], 'instructions', source)


def session_trajectory(sil_host, truth, relative_yaw=False):
    """cflib's `autonomy/autonomous_sequence_high_level.py`, unchanged: it
    uploads its figure-8 (ten Poly4D pieces) into the trajectory memory,
    defines it, resets the estimator, arms, takes off to 1 m, flies it with
    a relative start and lands; with `relative_yaw` (its `--relative-yaw`)
    it takes off turning to 3.14 / 2 rad and flies the figure-8 turned by
    as much. The truth against the figure-8 its pieces describe, in time:
    worst and RMS error over the whole trajectory from the start that fits
    best."""
    import numpy as np
    form = ' --relative-yaw' if relative_yaw else ''
    print(f'session 5{"b" if relative_yaw else ""}: cflib\'s autonomous_sequence_high_level.py{form}, unchanged '
          f'(an uploaded trajectory)')
    failed_before = check.failed
    script, example = figure8_example('cflib_example_figure8')  # only its definitions: it flies under __main__
    sil = Sil(sil_host, truth=truth)
    flown = []
    recording = threading.Event()
    recording.set()

    def record_truth():
        last = None
        while recording.is_set():
            m = truth.last
            if m is not None and m is not last:
                flown.append((m['t'], m['x'], m['y'], m['z']))
                last = m
            time.sleep(0.002)

    recorder = threading.Thread(target=record_truth, daemon=True)
    try:
        while truth.last is None:
            time.sleep(0.05)
        start = truth.pos
        recorder.start()
        if not QEMU:
            example_ran(run_example(script, 180, args=form.split()), script, 'The sequence is',
                        refuse='Upload failed')
        else:
            # The emulated image runs slower than the wall clock the
            # example sleeps on (its take-off would be cut short, its
            # trajectory landed half flown): its own upload, then its
            # sequence with its durations on the vehicle's clock.
            scf = connect()
            duration = fly_figure8(scf.cf, example, truth, relative_yaw=relative_yaw)
            print(f'  flown: {script.name}\'s upload_trajectory and sequence{form}, on the vehicle\'s clock '
                  f'(its trajectory {duration:.1f} s)')
            scf.close_link()
        truth.sleep(0.5)
        recording.clear()
        recorder.join()
        turn = 3.14 / 2 if relative_yaw else 0.0
        path = poly4d_path(example.figure8, (start[0], start[1], 1.0), turn=turn)
        track = np.array(flown) if flown else np.zeros((0, 4))
        high = track[track[:, 3] > 0.5]
        worst, rms, t0 = tracking_error(high, path) if len(high) > len(path) else (math.inf, math.inf, None)
        span = np.ptp(path, axis=0)
        check(worst <= TRAJ_TOL_M and rms <= TRAJ_RMS_TOL_M,
              f'the truth flew the uploaded figure-8 ({span[0]:.2f} x {span[1]:.2f} m, {len(example.figure8)} pieces, '
              f'{len(path) / 100:.1f} s{", turned " + format(turn, ".2f") + " rad" if turn else ""}): worst '
              f'{100 * worst:.1f} cm, RMS {100 * rms:.1f} cm over the whole of it, from plant time '
              f'{t0 or math.nan:.2f} s (bounds {100 * TRAJ_TOL_M:.0f} and {100 * TRAJ_RMS_TOL_M:.0f} cm)')
        image = 'crazyflie_qemu' if CRAZYFLIE else 'crtp_qemu' if QEMU else 'crtp_sil'
        image += '_turned' if relative_yaw else ''
        source = f'tools/crtp_cflib.py{" --qemu-crazyflie" if CRAZYFLIE else " --qemu" if QEMU else ""}'
        record(f'{image}_figure8_worst_cm', round(100 * worst, 1), 'cm', source)
        record(f'{image}_figure8_rms_cm', round(100 * rms, 1), 'cm', source)
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'landed after the trajectory: z {truth.last["z"]:.3f} m, motors off')
    finally:
        recording.clear()
        report(sil, failed_before)


def session_motion(sil_host, truth):
    """cflib's velocity and hover set-points, the generic port's types 8
    (velocity in the world) and 10 (hover: velocity in the body frame,
    yaw rate, height), as cflib's `send_velocity_world_setpoint` and its
    `MotionCommander` (the motion commander demos') send them: each move
    against the truth, so that a sign or a frame wrong is a move the wrong
    way. The motion commander times its moves on the wall clock (a velocity
    for distance / speed seconds): in the SIL the plant keeps wall time.

    A velocity set-point stops at once (a step to zero, as cflib sends it),
    and the vehicle carries on past the goal before it settles there: each
    move is checked `MOTION_SETTLE_S` after it ends, and the worst overshoot
    along the move, from the truth, is measured and reported."""
    from cflib.positioning.motion_commander import MotionCommander
    print('session 7: velocity and hover set-points (send_velocity_world_setpoint, MotionCommander)')
    failed_before = check.failed
    sil = Sil(sil_host, truth=truth)
    overshoots = []

    def moved(since, start, goal, what):
        """After the settle: the truth near `goal`; and how far past it, along
        the move from `start`, the track went meanwhile."""
        near(truth, goal, what)
        d = [g - s for g, s in zip(goal, start)]
        n = math.hypot(*d)
        past = max((sum((p - g) * c / n for p, g, c in zip(q, goal, d)) for q in truth.track[since:]),
                   default=math.nan)
        overshoots.append(max(past, 0.0))

    try:
        scf = connect()
        cf = scf.cf
        check(estimator_settled(scf), 'estimator converged (kalman.varP* spread < 1e-3)')
        cf.supervisor.send_arming_request(True)
        time.sleep(0.3)
        x0, y0, _ = truth.pos
        cf.high_level_commander.takeoff(0.5, 2.0)
        truth.sleep(3.0)
        # Type 8: 0.25 m/s along the world's y (left) for 2 s, then still.
        since, start = len(truth.track), truth.pos
        truth.sleep(2.0, every=lambda: cf.commander.send_velocity_world_setpoint(0.0, 0.25, 0.0, 0.0))
        truth.sleep(MOTION_SETTLE_S, every=lambda: cf.commander.send_velocity_world_setpoint(0.0, 0.0, 0.0, 0.0))
        moved(since, start, (x0, y0 + 0.5, 0.5), 'send_velocity_world_setpoint(0, 0.25, 0, 0) for 2 s')
        cf.commander.send_notify_setpoint_stop()
        cf.high_level_commander.land(0.0, 2.0)
        truth.sleep(3.0)
        x0, y0, _ = truth.pos
        # Type 10: MotionCommander takes off and moves in its body frame;
        # after a quarter turn left, forward is the world's left.
        with MotionCommander(scf, default_height=0.5) as mc:
            time.sleep(MOTION_SETTLE_S)
            near(truth, (x0, y0, 0.5), 'MotionCommander took off to 0.5 m')
            moves = [
                (lambda: mc.forward(0.4), (x0 + 0.4, y0, 0.5), 'mc.forward(0.4)'),
                (lambda: mc.up(0.3), (x0 + 0.4, y0, 0.8), 'mc.up(0.3)'),
                (lambda: mc.turn_left(90), None, None),
                (lambda: mc.forward(0.4), (x0 + 0.4, y0 + 0.4, 0.8),
                 'mc.turn_left(90) then mc.forward(0.4): the world\'s left'),
                (lambda: mc.right(0.4), (x0 + 0.8, y0 + 0.4, 0.8),
                 'mc.right(0.4) facing left: the world\'s forward'),
            ]
            for move, goal, what in moves:
                since, start = len(truth.track), truth.pos
                move()
                time.sleep(MOTION_SETTLE_S)
                if goal:
                    moved(since, start, goal, what)
        truth.sleep(1.0)
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'MotionCommander landed: z {truth.last["z"]:.3f} m, motors off')
        scf.close_link()
        worst = max(overshoots, default=math.nan)
        check(len(overshoots) == 5 and math.isfinite(worst),
              f'the moves\' overshoot past their goals, from the truth: worst {100 * worst:.1f} cm '
              f'({", ".join(f"{100 * o:.1f}" for o in overshoots)})')
        if len(overshoots) == 5 and math.isfinite(worst):
            record('crtp_sil_motion_overshoot_cm', round(100 * worst, 1), 'cm', 'crtp_cflib.py session 7')
    finally:
        report(sil, failed_before)


def passed(truth, since, goal, what):
    """The truth's track from entry `since` came within TOL_M of `goal`."""
    d = truth.closest(goal, since)
    check(d <= TOL_M, f'{what}: the truth passed {100 * d:.1f} cm from ({goal[0]}, {goal[1]}, {goal[2]}) '
                      f'(bound {100 * TOL_M:.0f} cm)')


def session_motion_examples(sil_host, truth):
    """cflib's `autonomy/motion_commander_demo.py` (hover set-points: moves,
    a half circle, a turn, a 3-D line, a started motion) and
    `autonomy/autonomous_sequence.py` (a take-off on velocity set-points,
    then position set-points, logging `kalman.stateX/Y/Z`), unchanged. The
    vehicle starts at the truth's origin facing x. Neither example checks
    for a deck: the SIL's position fixes are motion capture's (the deck
    flags say none is attached)."""
    print('session 8: cflib\'s motion_commander_demo.py and autonomous_sequence.py, unchanged')
    examples = cflib_examples() / 'autonomy'

    def demo(r, since):
        example_ran(r, examples / 'motion_commander_demo.py', 'Doing other work')
        # Its moves from the origin (MotionCommander's default height 0.3 m):
        # forward 0.8 and back; up 0.5 and down; right 0.5 and left; half a
        # circle right of radius 0.5 (to y -1, facing back); a quarter turn
        # left (facing right); 1 m back and 0.5 m up (to the origin, at
        # 0.8 m); left for a second at 0.5 m/s (the world's forward).
        for goal, what in (((0.8, 0.0, 0.3), 'mc.forward(0.8)'), ((0.0, 0.0, 0.8), 'mc.up(0.5)'),
                           ((0.0, -0.5, 0.3), 'mc.right(0.5, velocity=0.8)'),
                           ((0.0, -1.0, 0.3), 'mc.circle_right(0.5, velocity=0.5, angle_degrees=180)'),
                           ((0.0, 0.0, 0.8), 'mc.turn_left(90) then mc.move_distance(-1, 0.0, 0.5)')):
            passed(truth, since, goal, what)
        near(truth, (0.5, 0.0, 0.0), 'mc.start_left(velocity=0.5) for 1 s, then landed')
        check(not truth.last['flying'], 'motors off after the demo')

    def sequence(r, since):
        example_ran(r, examples / 'autonomous_sequence.py', 'pos: (')
        for goal in ((0.0, 0.0, 1.2), (0.5, -0.5, 1.2), (0.5, 0.5, 1.2), (-0.5, 0.5, 1.2), (-0.5, -0.5, 1.2),
                     (0.0, 0.0, 1.2), (0.0, 0.0, 0.4)):
            passed(truth, since, goal, f'send_position_setpoint{goal}')
        logged = [tuple(float(v) for v in m.groups())
                  for m in re.finditer(r'pos: \((\S+), (\S+), (\S+)\)', r.stdout)]
        high = [p for p in logged if p[2] > 1.0]
        check(len(high) >= 10, f'its kalman.stateX/Y/Z log: {len(logged)} positions, {len(high)} above 1 m')
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'send_stop_setpoint at the end: z {truth.last["z"]:.3f} m, motors off')

    for script, checks in (('motion_commander_demo.py', demo), ('autonomous_sequence.py', sequence)):
        failed_before = check.failed
        sil = Sil(sil_host, truth=truth)
        try:
            while truth.last is None:
                time.sleep(0.05)
            since = len(truth.track)
            r = run_example(examples / script, 120)
            truth.sleep(1.0)
            checks(r, since)
        finally:
            report(sil, failed_before)


def session_deck(sil_host, truth):
    """cflib's `step-by-step/sbs_motion_commander.py`, unchanged: it waits 5 s
    for `deck.bcFlow2` and stops without it ("No flow deck detected!", exit
    1), as on a Crazyflie without a Flow deck. With `sil-host crtp --deck
    bcFlow2` (the flag only, a stand-in: the position is the SIL's motion
    capture) it arms, logs the estimate, takes off to 0.5 m with a
    `MotionCommander`, hovers 3 s and lands; the truth holds 0.5 m over the
    hover, within 5 cm at worst."""
    print('session 9: cflib\'s sbs_motion_commander.py, unchanged: without a deck, then with the Flow deck\'s '
          'flag (sil-host crtp --deck bcFlow2)')
    script = cflib_examples() / 'step-by-step' / 'sbs_motion_commander.py'
    failed_before = check.failed
    sil = Sil(sil_host, truth=truth)
    try:
        r = run_example(script, 60)
        check(r.returncode == 1 and 'No flow deck detected!' in r.stdout and 'Deck is NOT attached!' in r.stdout,
              f'{script.name} without a deck: exit {r.returncode}, "No flow deck detected!" (as on a Crazyflie '
              f'without one)' + ('' if r.returncode == 1 else f'\n{r.stdout[-800:]}\n{r.stderr[-1500:]}'))
    finally:
        report(sil, failed_before)
    failed_before = check.failed
    sil = Sil(sil_host, '--deck', 'bcFlow2', truth=truth)
    try:
        while truth.last is None:
            time.sleep(0.05)
        since = truth.t
        r = run_example(script, 60)
        truth.sleep(1.0)
        example_ran(r, script, 'Deck is attached!')
        goal = (0.0, 0.0, 0.5)
        # The hover: from the first time the truth is within 1 cm of 0.5 m
        # high to the last (the climb and the descent at 0.2 m/s apart).
        track = [p for t, p in list(truth.tracks.get(0, [])) if t >= since]
        near_height = [i for i, p in enumerate(track) if abs(p[2] - goal[2]) <= 0.01]
        hover = track[near_height[0]:near_height[-1] + 1] if near_height else []
        worst = max((math.dist(p, goal) for p in hover), default=math.inf)
        check(len(hover) >= 200 and worst <= TOL_M,
              f'its MotionCommander took off to 0.5 m and hovered: {len(hover) / 100:.1f} s at 0.5 m, '
              f'worst {100 * worst:.1f} cm from (0, 0, 0.5) over it (bound {100 * TOL_M:.0f} cm)')
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'landed when the MotionCommander closed: z {truth.last["z"]:.3f} m, motors off')
    finally:
        report(sil, failed_before)


# Session 9's swarm: where each of the four starts (Crazyflie frame, m), a
# square 1 m a side about the origin, in the order of the example's URIs.
SWARM_STARTS = ((-0.5, 0.5), (0.5, 0.5), (0.5, -0.5), (-0.5, -0.5))


def session_swarm(sil_host, truth):
    """cflib's `step-by-step/sbs_swarm.py` with only its URIs changed (four
    `udp://` ports for its four radio addresses): `Swarm` opens the four
    links in parallel, writes `led.bitmask` (the light check), resets the
    four estimators, arms, takes off to 1 m, flies each its sequence of
    three relative go_to moves and lands. `sil-host crtp --count 4` flies
    the four in one world, each its own flight stack, sensors and port;
    each vehicle's truth against its take-off and the three corners its
    moves reach from where it starts, the four apart throughout (session
    10)."""
    print('session 10: cflib\'s sbs_swarm.py, its URIs only changed: four vehicles in one world '
          '(sil-host crtp --count 4)')
    failed_before = check.failed
    script = cflib_examples() / 'step-by-step' / 'sbs_swarm.py'
    uris = ''.join(f"    'udp://127.0.0.1:{PORT + i}',\n" for i in range(len(SWARM_STARTS)))
    text, changed = re.subn(r'^uris = \[\n.*?^\]', f'uris = [\n{uris}]', script.read_text(), count=1,
                            flags=re.DOTALL | re.MULTILINE)
    check(changed == 1, f'{script.name}: its uris list replaced ({changed} found)')
    work = pathlib.Path('target/cflib-swarm').resolve()
    work.mkdir(parents=True, exist_ok=True)
    (work / script.name).write_text(text)
    at = [a for x, y in SWARM_STARTS for a in ('--at', f'{x},{y}')]
    sil = Sil(sil_host, '--count', str(len(SWARM_STARTS)), *at, truth=truth)
    out = ''
    try:
        while len(truth.lasts) < len(SWARM_STARTS):
            time.sleep(0.05)
        since = truth.t
        # Its own cache (./cache) in the work directory, as a user's run.
        r = subprocess.run([sys.executable, script.name], check=False, capture_output=True, text=True,
                           timeout=180, cwd=work)
        truth.sleep(1.0)
        example_ran(r, script, 'Light check done')
        # Each sequence's moves (relative, 3 s each) from the start at 1 m.
        moves = (((-0.5, 0.5), (0.5, -0.5), (0.5, 0.0)), ((0.5, 0.5), (-0.5, -0.5), (0.0, -0.5)),
                 ((0.5, -0.5), (-0.5, 0.5), (-0.5, 0.0)), ((-0.5, -0.5), (0.5, 0.5), (0.0, 0.5)))
        for i, ((x, y), steps) in enumerate(zip(SWARM_STARTS, moves)):
            goals = [(x, y, 1.0)]
            for dx, dy in steps:
                goals.append((goals[-1][0] + dx, goals[-1][1] + dy, 1.0))
            misses = [truth.closest_of(i, g, since) for g in goals]
            check(max(misses) <= TOL_M,
                  f'vehicle {i} (udp port {PORT + i}, from ({x}, {y})): took off to 1 m and reached '
                  + ', '.join(f'({g[0]}, {g[1]})' for g in goals[1:])
                  + f', each within {100 * max(misses):.1f} cm (bound {100 * TOL_M:.0f} cm)')
            last = truth.lasts.get(i, {})
            end = (goals[-1][0], goals[-1][1], 0.0)
            off = math.dist(position_of(last), end) if last else math.inf
            check(off <= TOL_M and not last.get('flying', True),
                  f'vehicle {i} landed: {100 * off:.1f} cm from ({end[0]}, {end[1]}, 0), motors off')
        gap, when = truth.min_separation()
        check(gap >= 0.5, f'the four kept apart: the least distance between two, {gap:.3f} m at plant time '
                          f'{when} s (their moves bring two within 0.71 m; bound 0.5 m)')
        record('crtp_sil_swarm_min_separation_m', round(gap, 3), 'm', 'tools/crtp_cflib.py')
    finally:
        out = report(sil, failed_before)
    try:
        summary, _ = json.JSONDecoder().raw_decode(out[out.index('{'):])
    except ValueError:
        summary = {}
    vehicles = summary.get('vehicles', [])
    check(len(vehicles) == len(SWARM_STARTS) and all(v['packets']['handled'] > 100 for v in vehicles)
          and not summary.get('collisions') and not any(v['crashed'] for v in vehicles),
          f'sil-host flew {len(vehicles)} flight stacks, each its own link: '
          + ', '.join(f"{v['listen']} {v['packets']['handled']} packets" for v in vehicles)
          + f'; no collision (least distance {summary.get("min_separation_m", math.nan):.3f} m at 1 kHz), '
          f'{summary.get("late_steps")} steps late, real-time factor {summary.get("realtime_factor", 0):.2f}')


def radio_spec():
    """--radio's settings (fctools.radio.parse)."""
    from fctools.radio import parse
    return parse(RADIO)


def read_memory(cf, mem, length):
    """`length` bytes of `mem` from address 0, read with cflib's own
    `Memory.read` (chunks of 24 bytes, each asked until answered); None if
    it failed or took over 30 s."""
    done, got = threading.Event(), []

    def read(m, addr, data):
        if m.id == mem.id:
            got.append(bytes(data))
            done.set()

    def failed(m, addr, data):
        if m.id == mem.id:
            done.set()

    cf.mem.mem_read_cb.add_callback(read)
    cf.mem.mem_read_failed_cb.add_callback(failed)
    try:
        cf.mem.read(mem, 0, length)
        done.wait(30)
        return got[0] if got else None
    finally:
        cf.mem.mem_read_cb.remove_callback(read)
        cf.mem.mem_read_failed_cb.remove_callback(failed)


def session_radio(sil_host, truth):
    """cflib over a radio that loses packets (`--radio`, the bridge's model
    of the Crazyradio and the nRF51): connected (both TOCs whole, every
    value read), a parameter set and read back, a log block at 100 Hz, the
    example's figure-8 uploaded into the trajectory memory and read back
    byte for byte, then flown within session 5's bounds and landed; the
    radio's own counts checked in `report` (packets lost, the duplicates
    its retries made dropped, no link error)."""
    from cflib.crazyflie.mem import MemoryElement
    print(f'session R: over a radio that loses packets ({RADIO}): parameters, a log block, '
          f'the figure-8 uploaded, read back and flown')
    failed_before = check.failed
    _, example = figure8_example('cflib_example_figure8_radio')
    sil = Sil(sil_host, truth=truth)
    try:
        while truth.last is None:
            time.sleep(0.05)
        start, since = truth.pos, truth.t
        # Each transfer: completed exactly, failed cleanly (cflib said so),
        # or corrupted (completed, and not what was sent).
        transfers = {'completed': 0, 'failed': 0, 'corrupted': 0}
        scf = connect()
        cf = scf.cf
        transfers['completed' if cf.param.is_updated else 'failed'] += 1
        check(cf.param.is_updated,
              f'both TOCs whole and every value read: {sum(len(g) for g in cf.param.toc.toc.values())} params, '
              f'{sum(len(g) for g in cf.log.toc.toc.values())} log variables')
        before = float(cf.param.get_value('mpc.W_POS'))
        cf.param.set_value('mpc.W_POS', before * 2)
        after = read_back(cf, 'mpc.W_POS', before * 2, ask=True)
        cf.param.set_value('mpc.W_POS', before)
        restored = read_back(cf, 'mpc.W_POS', before, ask=True)
        for got, want in ((after, 2 * before), (restored, before)):
            transfers['completed' if got == want else 'corrupted'] += 1
        check(after == 2 * before and restored == before,
              f'param mpc.W_POS set to {2 * before:g} reads back {after:g}, and back to {restored:g}')
        stamps, errs = log_estimate(scf, truth)
        gaps = sorted(b - a for a, b in itertools.pairwise(stamps))
        transfers['completed' if len(stamps) == 100 else 'failed'] += 1
        check(gaps[1] >= 9 and gaps[-1] <= 11 and gaps[len(gaps) // 2] == 10 and max(errs) < 0.03,
              f'SyncLogger at 100 Hz: 100 samples, timestamps 10 ms apart (gaps {gaps[0]}–{gaps[-1]} ms), '
              f'stateEstimate within 3 cm of the truth (worst {100 * max(errs):.2f} cm)')
        duration = fly_figure8(cf, example, truth)
        mem = cf.mem.get_mems(MemoryElement.TYPE_TRAJ)[0]
        sent = b''.join(bytes(p.pack()) for p in mem.trajectory)
        got = read_memory(cf, mem, len(sent))
        # The upload (cflib's write_data_sync, inside the example: it exits
        # on a failed write) and the read back.
        transfers['completed'] += 1
        transfers['failed' if got is None else 'completed' if got == sent else 'corrupted'] += 1
        check(got == sent, f'the trajectory memory reads back the {len(sent)} bytes cflib wrote '
                           f'({len(mem.trajectory)} pieces): '
                           + ('the same' if got == sent else 'no answer' if got is None else
                              f'{sum(a != b for a, b in zip(got, sent))} bytes differ'))
        scf.close_link()
        truth.sleep(0.5)
        worst, rms = figure8_flown(truth, example, start, since)
        image = 'crazyflie_qemu_radio' if CRAZYFLIE else 'crtp_qemu_radio'
        tag, source = radio_tag()
        record(f'{image}_figure8_worst_cm', round(100 * worst, 1), 'cm', source)
        record(f'{image}_figure8_rms_cm', round(100 * rms, 1), 'cm', source)
        check(worst <= TRAJ_TOL_M and rms <= TRAJ_RMS_TOL_M,
              f'the figure-8 ({duration:.1f} s) over the radio: worst {100 * worst:.1f} cm, RMS {100 * rms:.1f} cm '
              f'(bounds {100 * TRAJ_TOL_M:.0f} and {100 * TRAJ_RMS_TOL_M:.0f} cm, as session 5)')
        check(truth.last['z'] < TOL_M and not truth.last['flying'],
              f'landed after it: z {truth.last["z"]:.3f} m, motors off')
        check(transfers['corrupted'] == 0 and transfers['failed'] == 0,
              f'transfers: {transfers["completed"]} completed exactly (the TOCs and values, two parameter writes '
              f'read back, the log block, the trajectory\'s upload and read back), {transfers["failed"]} failed, '
              f'{transfers["corrupted"]} corrupted')
        for k, n in transfers.items():
            record(f'{tag}_transfers_{k}', n, 'transfers', source)
    finally:
        report(sil, failed_before)


def persistent(cf, call, name):
    """cflib's `param.persistent_*` `call` on `name`, waited for: its result."""
    done = threading.Event()
    got = []
    getattr(cf.param, f'persistent_{call}')(name, lambda _, r: (got.append(r), done.set()))
    return got[0] if done.wait(5) else 'no answer'


def session_persistent(sil_host):
    """cflib's persistent parameters against `sil-host crtp --storage FILE`:
    stored, read back after a restart with the same file, cleared."""
    print('session 6: persistent parameters (cflib persistent_store / get_state / clear, sil-host --storage)')
    if QEMU:
        # The images keep their settings in a RAM stand-in for flash (QEMU
        # models no flash controller), which a restart of QEMU loses.
        print('  (not on the images: their settings store is a RAM stand-in in QEMU, lost on restart)')
        return
    store = pathlib.Path('target/cflib-persistent.bin').resolve()
    store.unlink(missing_ok=True)
    failed_before = check.failed
    sil = Sil(sil_host, '--storage', str(store))
    try:
        cf = connect().cf
        default = float(cf.param.get_value('mpc.W_POS'))
        kept, unkept = 2.5 * default, float(cf.param.get_value('pd.ROLL_P')) * 1.5
        elem = cf.param.toc.get_element_by_complete_name
        check(elem('mpc.W_POS').is_persistent() and not elem('stabilizer.estimator').is_persistent(),
              'the TOC marks the flight parameters persistent (extended type), not the Crazyflie aliases')
        cf.param.set_value('mpc.W_POS', kept)
        cf.param.set_value('pd.ROLL_P', unkept)
        time.sleep(0.3)
        ok = persistent(cf, 'store', 'mpc.W_POS')
        state = persistent(cf, 'get_state', 'mpc.W_POS')
        check(ok is True and state and state.is_stored and abs(state.stored_value - kept) < 1e-6
              and abs(state.default_value - default) < 1e-6,
              f'mpc.W_POS = {kept:g} stored ({ok}); its state: {state}')
        cf.param.set_value('ring.effect', 10)
        time.sleep(0.3)
        ok = persistent(cf, 'store', 'ring.effect')
        check(ok is True, f'ring.effect = 10 stored ({ok}), beside the flight parameters')
        cf.close_link()
    finally:
        report(sil, failed_before)
    sil = Sil(sil_host, '--storage', str(store))
    try:
        cf = connect().cf
        w_pos, roll = float(cf.param.get_value('mpc.W_POS')), float(cf.param.get_value('pd.ROLL_P'))
        check(abs(w_pos - kept) < 1e-6 and abs(roll - unkept) > 1e-6,
              f'after a restart with the same file mpc.W_POS is {w_pos:g} (stored), pd.ROLL_P {roll:g} '
              f'(set, not stored: its default)')
        effect = int(cf.param.get_value('ring.effect'))
        check(effect == 10 and 'other persistent parameter(s) taken' in ''.join(sil.err),
              f'and ring.effect is {effect} (stored; the console: taken at boot)')
        ok = persistent(cf, 'clear', 'ring.effect')
        check(ok is True, f'ring.effect cleared ({ok})')
        ok = persistent(cf, 'clear', 'mpc.W_POS')
        state = persistent(cf, 'get_state', 'mpc.W_POS')
        check(ok is True and state and not state.is_stored, f'cleared ({ok}); its state: {state}')
        cf.close_link()
    finally:
        out = report(sil, failed_before)
    check('storage' in out and 'settings found in flash' in out,
          'sil-host said at boot what it found: ' + next((ln for ln in out.splitlines() if 'storage ' in ln), '?'))
    sil = Sil(sil_host, '--storage', str(store))
    try:
        cf = connect().cf
        w_pos = float(cf.param.get_value('mpc.W_POS'))
        check(abs(w_pos - default) < 1e-6, f'after the clear and a restart mpc.W_POS is its default, {w_pos:g}')
        cf.close_link()
    finally:
        report(sil, failed_before)


def main():
    sil_host = sys.argv[1]
    cflib.crtp.init_drivers()
    truth = Truth(TRUTH_PORT)
    truth.follow()
    if RADIO:
        if not QEMU:
            sys.exit('crtp_cflib.py: --radio models the nRF51 bridge\'s radio: with --qemu or --qemu-crazyflie')
        session_radio(sil_host, truth)
        truth.close()
        counts = RADIOS[-1] if RADIOS else {}
        tag, source = radio_tag()
        if counts:
            record(f'{tag}_lost_pct', round(100 * counts['lost_on_air'] / max(counts['on_air'], 1), 1), '%', source)
            dups = counts['retransmits'] + counts['duplicates']
            record(f'{tag}_duplicates_dropped_pct', round(100 * dups / max(counts['on_air'], 1), 1), '%', source)
            record(f'{tag}_link_errors', counts['link_errors'], 'errors', source)
        print(check.summary())
        sys.exit(check.exit_code())
    session_high_level(sil_host, truth)
    session_extpos(sil_host, truth)
    session_dead_imu(sil_host, truth)
    if not QEMU:
        session_fix_faults(sil_host, truth)
    session_examples(sil_host)
    session_trajectory(sil_host, truth)
    session_trajectory(sil_host, truth, relative_yaw=True)
    session_persistent(sil_host)
    if not QEMU:
        session_motion(sil_host, truth)
        session_motion_examples(sil_host, truth)
        session_deck(sil_host, truth)
        session_swarm(sil_host, truth)
    session_flood(sil_host, truth)
    truth.close()
    plant = sum(p for p, _ in truth.walls)
    wall = sum(w for _, w in truth.walls)
    print(f'the plant flew {plant:.1f} s in {wall:.1f} s of wall time (real-time factor {plant / max(wall, 1e-9):.2f})')
    if TIMINGS:
        image = 'crazyflie' if CRAZYFLIE else 'crtp'
        source = f'tools/crtp_cflib.py --qemu{"-crazyflie" if CRAZYFLIE else ""}'
        record(f'{image}_qemu_answer_worst_icount', max(a for a, _, _ in TIMINGS), 'instructions', source)
        record(f'{image}_qemu_late_steps', sum(n for _, n, _ in TIMINGS), 'steps', source)
        record(f'{image}_qemu_design_passed_steps', sum(p for _, _, p in TIMINGS), 'steps', source)
        record(f'{image}_qemu_stack_boot_bytes', max(b for b, _ in STACKS), 'bytes', source)
        record(f'{image}_qemu_stack_tasks_bytes', max(t for _, t in STACKS), 'bytes', source)
        record(f'{image}_qemu_link_hold_worst_icount', max(HOLDS), 'instructions', source)
        # A sample that comes ready just as the longest hold starts waits
        # for it, then takes a step: what that costs at worst, beside the
        # step's budget. Shown, not held to it here: the worst step moves by
        # about 2 000 instructions from run to run with where the radio's
        # unpaced bytes land, more than the margin; the budget harness holds
        # the same sum, without interrupts (the book's firmware chapter).
        worst = max(HOLDS) + max(a for a, _, _ in TIMINGS)
        print(f'the longest hold and the worst step together: {max(HOLDS)} + {max(a for a, _, _ in TIMINGS)} = '
              f'{worst} instructions, beside the step\'s budget of {budgets()["budget_image_step_instructions"]} '
              f'(information)')
        record(f'{image}_qemu_hold_and_step_worst_icount', worst, 'instructions', source)
    print(check.summary())
    sys.exit(check.exit_code())


if __name__ == '__main__':
    main()
