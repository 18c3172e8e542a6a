"""Crazyflie trajectories as pieces of polynomials, evaluated here with
numpy (not by the flight controller's planner): the uploaded trajectory a
rotorpy flight is measured against (`tools/rotorpy_hil.py --trajectory`).

A piece is the Crazyflie's `Poly4D` row: its duration, then x, y, z and
yaw's eight coefficients each, from the constant up, in the Crazyflie's
world frame (x forward, y left, z up; yaw counter-clockwise seen from
above). The files are its own CSV (`uav_trajectories`, one piece a row, a
header allowed). The pieces of cflib's own examples come from its PyPI
source distribution (`cflib_examples`), unchanged.
"""
import importlib.metadata
import importlib.util
import math
import os
import pathlib
import shutil
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

# The Crazyflie's world frame in NED: north = x, east = -y, down = -z,
# heading = -yaw (fc_loop::trajectory::AXIS_SIGNS).
AXIS_SIGNS = np.array([1.0, -1.0, -1.0, -1.0])


def cflib_examples():
    """cflib's examples, unchanged, from its PyPI source distribution (the
    installed version): their directory. Fetched and unpacked once, each
    step into a directory of its own and then renamed into place, so that
    flights started together each see it whole."""
    version = importlib.metadata.version('cflib')
    work = pathlib.Path('target/cflib-examples').resolve()
    work.mkdir(parents=True, exist_ok=True)
    tree = work / f'cflib-{version}'
    if not (tree / 'examples').is_dir():
        tmp = pathlib.Path(tempfile.mkdtemp(dir=work))
        try:
            sdist = work / f'cflib-{version}.tar.gz'
            if not sdist.exists():
                subprocess.run([sys.executable, '-m', 'pip', 'download', '--quiet', '--no-deps', '--no-binary',
                                ':all:', f'cflib=={version}', '-d', str(tmp)], check=True)
                os.replace(tmp / sdist.name, sdist)
            with tarfile.open(sdist) as tar:
                tar.extractall(tmp, filter='data')
            try:
                os.rename(tmp / tree.name, tree)
            except OSError:
                pass  # another flight's is in place
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return tree / 'examples'


def cflib_figure8():
    """The figure-8 of cflib's `autonomy/autonomous_sequence_high_level.py`
    (its `figure8` rows), read from the example itself."""
    script = cflib_examples() / 'autonomy' / 'autonomous_sequence_high_level.py'
    spec = importlib.util.spec_from_file_location('cflib_example_figure8_rows', script)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)  # only its definitions: it flies under __main__
    return [list(map(float, row)) for row in example.figure8]


def read_csv(path):
    """The pieces of a Crazyflie trajectory file (a header row allowed)."""
    rows = []
    for i, line in enumerate(pathlib.Path(path).read_text().splitlines()):
        cells = [c.strip() for c in line.split(',') if c.strip()]
        if not cells or line.lstrip().startswith('#'):
            continue
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            if i == 0:
                continue
            raise
    return rows


def write_csv(rows, path):
    """`rows` as a Crazyflie trajectory file, with its header."""
    head = ['Duration'] + [f'{a}^{k}' for a in ('x', 'y', 'z', 'yaw') for k in range(8)]
    lines = [','.join(head)] + [','.join(repr(float(v)) for v in row) for row in rows]
    pathlib.Path(path).write_text('\n'.join(lines) + '\n')


class Pieces:
    """A trajectory flown relative to where it starts (`start_ned_m`), as
    `start_trajectory(..., relative_position=True)` flies it, its heading
    its own: NED position and its first four derivatives, and the heading
    with its rate, at `tau` s from its start (at rest at its end after it)."""

    def __init__(self, rows, start_ned_m):
        self.rows = [np.asarray(r, dtype=float) for r in rows]
        self.durations = np.array([r[0] for r in self.rows])
        self.duration_s = float(self.durations.sum())
        self.start_ned_m = np.asarray(start_ned_m, dtype=float)
        self.first = self._raw(0.0)[0][:3]

    def _raw(self, tau):
        """[position/heading, d/dt, ..., d⁴/dt⁴] in NED, unshifted."""
        tau = min(max(tau, 0.0), self.duration_s)
        i = 0
        while i + 1 < len(self.rows) and tau > self.durations[i]:
            tau -= self.durations[i]
            i += 1
        tau = min(tau, self.durations[i])
        out = np.zeros((5, 4))
        for axis in range(4):
            c = np.polynomial.Polynomial(self.rows[i][1 + 8 * axis:9 + 8 * axis])
            for d in range(5):
                out[d, axis] = AXIS_SIGNS[axis] * c.deriv(d)(tau) if d else AXIS_SIGNS[axis] * c(tau)
        return out

    def at(self, tau):
        """(pos, vel, acc, jerk, snap), NED; the derivatives zero after its end."""
        raw = self._raw(tau)
        if tau >= self.duration_s:
            raw[1:] = 0.0
        pos = raw[0, :3] - self.first + self.start_ned_m
        return pos, raw[1, :3], raw[2, :3], raw[3, :3], raw[4, :3]

    def heading(self, tau):
        """Heading (NED, rad, wrapped) and its rate."""
        raw = self._raw(tau)
        rate = raw[1, 3] if tau < self.duration_s else 0.0
        return math.remainder(raw[0, 3], 2 * math.pi), rate
