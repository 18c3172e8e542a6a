#!/usr/bin/env python3
"""cfclient (PyPI, unmodified) connects to `sil-host crtp` under Xvfb; a
screenshot of its flight tab.

A user's steps, done by X events: cfclient starts with `udp://127.0.0.1:19850`
as its last link (its own config file, in a scratch HOME), its start-up scan
finds the vehicle, a click on "Connect" connects. Checked from
cfclient's own log:

1. the connection completes (cflib's "Connection completed");
2. every parameter is read ("All parameters updated") and the flight tab's
   log blocks start (attitude, battery, state estimate, motors);
3. nothing raised in cfclient's callbacks (no traceback in its log);
4. the screenshot (the flight tab: attitude indicator, battery, state
   estimate) is written.

Prints `cfclient check: N passed, M failed`; exits 1 on any failure.
Usage: cfclient_shot.py SIL_HOST CFCLIENT [--out FILE.png] [--hold S]
  CFCLIENT: the cfclient executable (e.g. a venv's bin/cfclient);
  --hold: seconds of flight data shown before the screenshot (default 6).
Needs Xvfb, xdotool and ImageMagick's `import` (./test.sh installs them).
"""
import argparse
import json
import os
import pathlib
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from fctools.checks import Checks

PORT = 19850
URI = f'udp://127.0.0.1:{PORT}'
DISPLAY = ':97'
SIZE = (1280, 860)
CONNECT_XY = ('305', '47')

check = Checks('cfclient')


def wait_for(pred, secs, step=0.2):
    end = time.time() + secs
    while time.time() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('sil_host')
    ap.add_argument('cfclient')
    ap.add_argument('--out', default='target/cfclient-flight-tab.png')
    ap.add_argument('--hold', type=float, default=6.0)
    a = ap.parse_args()
    for tool in ('Xvfb', 'xdotool', 'import'):
        if not shutil.which(tool):
            sys.exit(f'cfclient_shot: {tool} is not installed (apt: xvfb, xdotool, imagemagick)')
    if not 0.0 <= a.hold <= 120.0:
        sys.exit(f'cfclient_shot: --hold {a.hold} is out of range [0, 120] s')

    home = pathlib.Path(tempfile.mkdtemp(prefix='cfclient-home-'))
    conf = home / '.config' / 'cfclient'
    conf.mkdir(parents=True)
    # What cfclient writes after a session with this link: it selects the URI
    # when its start-up scan finds it.
    (conf / 'config.json').write_text(json.dumps({'link_uri': URI, 'window_size': list(SIZE)}))
    env = dict(os.environ, HOME=str(home), DISPLAY=DISPLAY, XDG_CONFIG_HOME=str(home / '.config'),
               QT_QPA_PLATFORM='xcb')
    log = home / 'cfclient.log'
    procs = []
    try:
        sil = subprocess.Popen([a.sil_host, 'crtp', '--listen', f'127.0.0.1:{PORT}', '--duration', '300'],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        procs.append(sil)
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.settimeout(0.2)

        def answers():
            try:
                probe.sendto(b'\xff', ('127.0.0.1', PORT))
                probe.recv(64)
                return True
            except OSError:
                return False

        if not wait_for(answers, 20):
            sys.exit('cfclient_shot: sil-host crtp does not answer on ' + URI)
        probe.close()
        xvfb = subprocess.Popen(['Xvfb', DISPLAY, '-screen', '0', f'{SIZE[0]}x{SIZE[1]}x24', '-nolisten', 'tcp'],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        procs.append(xvfb)
        time.sleep(1.0)
        with open(log, 'w') as f:
            cfc = subprocess.Popen([a.cfclient], env=env, stdout=f, stderr=subprocess.STDOUT)
        procs.append(cfc)

        def window():
            r = subprocess.run(['xdotool', 'search', '--onlyvisible', '--name', '.'], check=False, env=env,
                               capture_output=True, text=True)
            ids = r.stdout.split()
            return ids[0] if ids else None

        if not wait_for(lambda: window() is not None, 60):
            sys.exit(f'cfclient_shot: no cfclient window after 60 s; its log:\n{log.read_text()[-3000:]}')
        # The start-up scan (every driver, the UDP one probing 19850-19859).
        time.sleep(8.0)
        # Its "Connect" button, right of the interface list (cfclient 2026.8.1's
        # layout; without a window manager the window is never active, so its
        # Ctrl+I shortcut does not fire).
        subprocess.run(['xdotool', 'mousemove', '--window', window(), *CONNECT_XY, 'click', '1'], env=env,
                       check=True)
        text = lambda: log.read_text(errors='replace')
        connected = wait_for(lambda: f'Connection completed [{URI}]' in text(), 30)
        check(connected, f'cfclient connected to {URI} (its "Connection completed")')
        blocks = wait_for(lambda: text().count('Have successfully started logging') >= 3, 10)
        check('All parameters updated' in text() and blocks,
              f'all parameters read; {text().count("Have successfully started logging")} of the flight tab\'s '
              'log blocks started')
        time.sleep(a.hold)
        out = pathlib.Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(['import', '-window', 'root', '-crop', f'{SIZE[0]}x{SIZE[1]}+0+0', str(out)], env=env,
                       check=True)
        check(out.exists() and out.stat().st_size > 20_000, f'screenshot {out} ({out.stat().st_size} B)')
        bad = [ln for ln in text().splitlines() if 'Traceback' in ln or 'Exception while' in ln]
        check(not bad, 'nothing raised in cfclient' + ('' if not bad else f': {bad[:3]}\n{text()[-3000:]}'))
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        shutil.rmtree(home, ignore_errors=True)
    print(check.summary())
    sys.exit(check.exit_code())


if __name__ == '__main__':
    main()
