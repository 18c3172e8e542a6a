#!/usr/bin/env python3
"""The images as a board gets them, checked from their bytes (what
`./test.sh` held in inline programs before):

    python3 tools/check_images.py bin target/hardware/firmware-crazyflie.bin
        the file cfloader and dfu-util write at 0x08004000 begins with the
        image's vector table: the initial SP inside the 128 KiB SRAM, 8-byte
        aligned; a Thumb reset vector inside the image
    python3 tools/check_images.py as-flashed ELF
        the Crazyflie image as flashed (binutils' `size -A`) within its
        budgets (firmware/stm32f405/src/budgets.rs), its figures recorded
    python3 tools/check_images.py headroom target/measurements.json
        each image's flash headroom under its budget (information)
"""
import argparse
import json
import struct
import subprocess
import sys

from fctools.checks import Checks
from measure import budgets, record

SRAM = (0x20000000, 0x20020000)
FLASH = (0x08000000, 0x08100000)
CRAZYFLIE_BASE = 0x08004000


def check_bin(path, check):
    with open(path, "rb") as f:
        b = f.read()
    sp, reset = struct.unpack("<II", b[:8])
    check(SRAM[0] < sp < SRAM[1] and sp % 8 == 0 and CRAZYFLIE_BASE < reset < CRAZYFLIE_BASE + len(b) and reset & 1,
          f"{path}: {len(b)} B for {CRAZYFLIE_BASE:#x}, SP {sp:#x}, reset {reset:#x} (a vector table)")


def footprint(elf):
    """Flash (sections in flash, and .data's initial values) and static RAM, bytes."""
    out = subprocess.run(["size", "-A", elf], capture_output=True, text=True, check=True).stdout
    flash = ram = 0
    for line in out.splitlines():
        f = line.split()
        if len(f) != 3 or not f[1].isdigit() or not f[2].isdigit():
            continue
        name, size, addr = f[0], int(f[1]), int(f[2])
        if FLASH[0] <= addr < FLASH[1] and name != ".uninit":
            flash += size
        if name == ".data":
            flash += size
        if SRAM[0] <= addr < SRAM[1]:
            ram += size
    return flash, ram


def check_as_flashed(elf, check):
    flash, ram = footprint(elf)
    b = budgets()
    budget = (b["budget_crazyflie_as_flashed_flash_bytes"], b["budget_crazyflie_as_flashed_static_ram_bytes"])
    for key, v in (("flash", flash), ("static_ram", ram), ("flash_headroom", budget[0] - flash)):
        record(f"crazyflie_image_as_flashed_{key}_bytes", v, "B", "test.sh: size -A")
    check(flash <= budget[0] and ram <= budget[1],
          f"firmware-crazyflie as flashed: flash {flash} B of {budget[0]}, static RAM {ram} B of {budget[1]}")


def headroom(path):
    with open(path) as f:
        m = json.load(f)["measurements"]
    suffix = "_flash_headroom_bytes"
    for name, v in sorted((k[: -len(suffix)], v["value"]) for k, v in m.items() if k.endswith(suffix)):
        print(f"headroom: {name}: {v:.0f} B of flash under its budget")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("bin", "as-flashed", "headroom"))
    ap.add_argument("path")
    a = ap.parse_args()
    if a.what == "headroom":
        headroom(a.path)
        return 0
    check = Checks("image")
    (check_bin if a.what == "bin" else check_as_flashed)(a.path, check)
    print(check.summary())
    return check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
