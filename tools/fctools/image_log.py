"""What an image in QEMU logged, read by the check scripts.

`stack(text)`: the image's stack figures (fc_stm32f405::stack): the boot's
high-water mark (`stack: boot reached N bytes`, logged as the idle task
starts, before the stack is painted again) and the tasks' since then (the
last `stack: high-water N bytes of M` line, logged with the timing line when
the mark has grown), in bytes.

`link_hold(text)`: the longest the CRTP images' link task held the vehicle
(fc_stm32f405::timing::Holds: the last `link: held the vehicle up to N
instructions` line, logged with the timing line when it has grown).
"""
import re

BOOT_LINE = re.compile(r"stack: boot reached (\d+) bytes")
TASKS_LINE = re.compile(r"stack: high-water (\d+) bytes of (\d+)")
HOLD_LINE = re.compile(r"link: held the vehicle up to (\d+) instructions")


def stack(text):
    """(boot, tasks, capacity) in bytes from the image's log `text` (a
    string or a list of lines): the boot's mark, the tasks' last mark and
    the bytes the stack may grow to; 0 for a figure it did not log."""
    if not isinstance(text, str):
        text = "\n".join(text)
    boot = BOOT_LINE.findall(text)
    tasks = TASKS_LINE.findall(text)
    return (int(boot[-1]) if boot else 0,
            int(tasks[-1][0]) if tasks else 0,
            int(tasks[-1][1]) if tasks else 0)


def link_hold(text):
    """The longest hold of the vehicle by the link's task the image logged
    in `text` (a string or a list of lines), instructions; 0 if none."""
    if not isinstance(text, str):
        text = "\n".join(text)
    held = HOLD_LINE.findall(text)
    return int(held[-1]) if held else 0
