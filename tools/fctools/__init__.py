"""Helpers the check scripts in tools/ share.

- `checks.Checks`: a script's checks, each printed as it is made, counted,
  and summed up in the `NAME check: N passed, M failed` line ./test.sh
  counts;
- `truth.Truth`: a simulator's true state, read from its UDP stream of JSON
  datagrams (rotorpy's through tools/rotorpy_hil.py, or `sil-host crtp
  --truth-to`);
- `image_log.stack`: the stack's high-water marks (the boot's, the tasks')
  an image in QEMU logged.

The scripts run as `python3 tools/SCRIPT.py`, so `tools/` is on their path
and `from fctools.checks import Checks` needs no install.
"""
